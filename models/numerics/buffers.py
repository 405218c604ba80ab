"""CasADi Functions evaluated on numpy buffers of their own.

Calling a Function with numpy arrays converts every argument to a DM and every output back, element by element:
for the plant's 262 states at 350 samples that was 15 to 20 ms of a throw's 90, for training's Jacobians most of
an iteration. The models layer's hot calls go through InPlace instead.
"""
from __future__ import annotations

import casadi as ca
import numpy as np


class InPlace:
    """A CasADi Function evaluated on its own numpy buffers: no DM is made per call.

    Arguments are copied into the input buffers (column-major, as CasADi stores them); the outputs
    come back as new arrays shaped like the Function's outputs. One set of buffers per Function, so
    calls must not overlap (the diagnoser diagnoses in one thread).
    """

    def __init__(self, function: ca.Function):
        self.function = function
        self._buffer, self._trigger = function.buffer()
        self._inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self._outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        self._views = [out.reshape(function.size_out(i), order="F") for i, out in enumerate(self._outputs)]
        for i, slot in enumerate(self._inputs):
            self._buffer.set_arg(i, memoryview(slot))
        for i, slot in enumerate(self._outputs):
            self._buffer.set_res(i, memoryview(slot))

    def __call__(self, *args) -> list[np.ndarray]:
        """The outputs, as new arrays."""
        return [view.copy() for view in self.views(*args)]

    def views(self, *args) -> list[np.ndarray]:
        """The outputs as views of the output buffers, shaped: valid until the next call (for a caller that copies
        them where they go; a view passed back as an argument is read before the call overwrites it)."""
        for slot, value in zip(self._inputs, args, strict=True):
            slot[:] = np.asarray(value, dtype=float).ravel(order="F")
        self._trigger()
        return self._views
