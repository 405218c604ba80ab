"""Machine code for the models' CasADi Functions: compiled once per machine and cached, or once per process.

The models layer builds Functions and takes a `Compiler` (models/reduced/hybrid.py) that returns equivalent
ones; this is the one that compiles. The cache lives in $RAILSWITCH_CACHE, else the user's cache
directory ($XDG_CACHE_HOME or ~/.cache, then railswitch); where that cannot be made, each process
compiles for itself.
"""
from __future__ import annotations

import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np

from railswitch.models.plant.high_fidelity import Plant, PlantParams
from railswitch.services.adapters.user_directories import user_directory


def default_cache_dir() -> Path | None:
    """$RAILSWITCH_CACHE, else the user's cache directory; None when it cannot be made."""
    try:
        cache_dir = user_directory("RAILSWITCH_CACHE", "XDG_CACHE_HOME", (".cache",))
        cache_dir.mkdir(parents=True, exist_ok=True)
        return cache_dir
    except (OSError, RuntimeError):  # RuntimeError: no home directory
        return None


class MachineCode:
    """A Compiler for the models: Functions in, machine-code Functions out (the same ones without a C compiler).

    `machine_code` says whether everything it was given so far is machine code."""

    def __init__(self, cache_dir: Path | None = None, *, cached: bool = True, exact: bool = False):
        """`exact`: plain -O2 (EXACT), for training, instead of OPTIMISATION."""
        self.cache_dir = (cache_dir or default_cache_dir()) if cached else None
        self.optimisation = EXACT if exact else OPTIMISATION
        self.machine_code = True
        self.calls = 0  # sets of Functions made machine code (compiled, or loaded from the cache)

    def __call__(self, functions: list[ca.Function], with_jacobian: bool = False) -> list[ca.Function]:
        """`with_jacobian`: each Function's Jacobian goes into its machine code too, where CasADi finds it
        (`jac_<name>`), for a solver that asks for it (the plant's CVODES)."""
        self.calls += 1
        compiled, ok = jit_compiled_all(functions, self.cache_dir, with_jacobian, self.optimisation)
        self.machine_code = self.machine_code and ok
        return compiled

    def kernel(self, name: str, body: str, inputs: dict[str, int], outputs: dict[str, int]) -> ca.Function | None:
        """A Function from a C body (CasADi's Function.jit: `inputs` and `outputs` name its dense columns and their
        sizes), or None without a C compiler. Its body goes into the generated code of every Function that calls
        it, so it is compiled with them, with their flags and cache; CasADi also compiles it alone once (a tenth
        of a second), for calls outside machine code."""
        compiler = c_compiler()
        if compiler is None:
            return None
        sparsities = [ca.Sparsity.dense(n) for n in (*inputs.values(), *outputs.values())]
        try:
            scratch = tempfile.mkdtemp(prefix="railswitch-kernel-")  # not the working directory, which may be read-only
        except OSError:  # nowhere to compile it: the models write the features out instead
            return None
        try:
            return ca.Function.jit(name, body, list(inputs), list(outputs), sparsities[:len(inputs)],
                                   sparsities[len(inputs):],
                                   {"compiler": "shell", "jit_cleanup": False,  # removed here, below
                                    "jit_options": {"compiler": compiler, "flags": list(self.optimisation),
                                                    "directory": scratch + os.sep, "cleanup": False, "verbose": False}})
        except RuntimeError:  # the compiler failed on it: the models write the features out instead
            return None
        finally:
            shutil.rmtree(scratch, ignore_errors=True)  # its library is loaded already


# How the C compiler optimises the models. Beyond -O2:
# - a division by a value used more than once becomes one reciprocal and products (-freciprocal-math: the
#   reduced models' steps solve small linear systems and the networks divide by square roots, a good part of a
#   throw's diagnosis), and a square root need not set errno;
# - the machine's own instructions (-march=native: fused multiply-adds, wide registers) and sums and products
#   taken in any order (-fassociative-math, with no traps and no signed zeros, which it needs), so the compiler
#   can pair the K sensitivity directions' identical operations: the Jacobian chunks markedly faster (causal's
#   most), a rollout a little.
# All move results by a rounding or so per operation, far inside the solvers' tolerances; infinities and NaNs
# keep their meaning (no -ffinite-math-only), which the estimator relies on to reject a diverged rollout. The
# code is this processor's, so the cache's key names the processor (_machine).
OPTIMISATION = ("-O2", "-fno-math-errno", "-freciprocal-math", "-march=native", "-fno-trapping-math", "-fno-signed-zeros",
                "-fassociative-math")
# Training's (its plant data and its own functions): IEEE arithmetic as written. The causal rail's fits run for
# hundreds of iterations from a seeded start and end in another optimum when a rounding per operation moves (as it
# moves the plant's rail: docs/results.md): trained under OPTIMISATION it followed the plant far worse over the 25
# validation series of benchmarks.reduced, on average and at worst, than trained under EXACT.
EXACT = ("-O2",)
SHARED = ("-shared", "-fPIC")  # beside the optimisation, the flags of a cached shared library (all part of its key)


def jit_compiled_all(functions: list[ca.Function], cache_dir: Path | None = None, with_jacobian: bool = False,
                     optimisation: tuple[str, ...] = OPTIMISATION) -> tuple[list[ca.Function], bool]:
    """The same Functions compiled to machine code (needs a C compiler), else themselves; True when every
    one is machine code.

    With `cache_dir`, the machine code is kept there and later calls, in any process, load it instead
    of compiling again (the missing libraries compiled in parallel, one C compiler per core); without
    one, or when the cache fails, CasADi's JIT compiles them for this process.
    """
    if cache_dir is not None:
        try:
            return cached_externals(functions, Path(cache_dir), with_jacobian, optimisation), True
        except (OSError, RuntimeError, subprocess.SubprocessError):
            pass  # no compiler, or the cache is not writable: compiled for this process only
    compiled = [_process_jit(function, optimisation) for function in functions]
    return [f for f, _ in compiled], all(ok for _, ok in compiled)


def _process_jit(function: ca.Function, optimisation: tuple[str, ...]) -> tuple[ca.Function, bool]:
    """CasADi's own JIT, for this process only; the Function itself when that fails."""
    try:
        symbols = function.mx_in()
        scratch = tempfile.gettempdir()  # CasADi's intermediate files stay out of the user's directory
        compiled = ca.Function(function.name() + "_jit", symbols, function.call(symbols),
                               function.name_in(), function.name_out(),
                               {"jit": True, "compiler": "shell", "jit_name": "railswitch_jit",
                                "jit_options": {"flags": list(optimisation), "verbose": False,
                                                "directory": scratch + os.sep}})
        compiled(*[np.zeros(function.size_in(i)) for i in range(function.n_in())])
        return compiled, True
    except RuntimeError:
        return function, False


def cached_externals(functions: list[ca.Function], cache_dir: Path, with_jacobian: bool = False,
                     optimisation: tuple[str, ...] = OPTIMISATION) -> list[ca.Function]:
    """Each function from `<cache_dir>/<key>.so`, compiled from its generated C code first if not there yet.

    The key hashes the C source, CasADi's version, the processor (_machine) and the flags, so a changed model,
    CasADi or flag set gets its own library. A library is compiled under a temporary name and renamed
    into place (atomic), so processes compiling the same one at once never load a partial file. The C
    code is generated here, one function after the other; only the compilers run in parallel.
    """
    flags = (*optimisation, *SHARED)
    libraries, missing = [], {}
    for function in functions:
        generator = ca.CodeGenerator("railswitch_cache.c", {"with_header": False})
        generator.add(function)
        if with_jacobian:
            generator.add(function.jacobian())
        source = generator.dump()
        key = hashlib.sha256("\n".join([ca.__version__, _machine(), *flags, source]).encode()).hexdigest()
        libraries.append(cache_dir / f"{key[:32]}.so")
        if not libraries[-1].exists():
            missing[libraries[-1]] = source
    if missing:
        compiler = c_compiler()
        if compiler is None:
            raise FileNotFoundError("no C compiler (gcc or cc) on PATH")
        with ThreadPoolExecutor(max_workers=min(len(missing), os.cpu_count() or 1)) as pool:
            compiles = [pool.submit(_compile, compiler, flags, source, library) for library, source in missing.items()]
            for done in compiles:
                done.result()  # raises the first failure
    return [ca.external(function.name(), str(library)) for function, library in zip(functions, libraries)]


def c_compiler() -> str | None:
    """The C compiler on PATH (gcc, else cc), or None."""
    return shutil.which("gcc") or shutil.which("cc")


@lru_cache(maxsize=1)
def _machine() -> str:
    """The processor the code is compiled for: its architecture, and on Linux its model and instruction sets (a
    cache shared by machines of other processors never hands one code it cannot run)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return f"{platform.machine()} {platform.processor()}"
    first = {}
    for line in lines:
        name, _, value = line.partition(":")
        first.setdefault(name.strip(), value.strip())
    return " ".join([platform.machine(), first.get("model name", ""), first.get("flags", first.get("Features", ""))])


def _compile(compiler: str, flags: tuple[str, ...], source: str, library: Path) -> None:
    with tempfile.TemporaryDirectory(dir=library.parent) as scratch:  # same file system: the rename is atomic
        c_file, partial = Path(scratch) / "railswitch_cache.c", Path(scratch) / "library.so"
        c_file.write_text(source)
        subprocess.run([compiler, *flags, str(c_file), "-o", str(partial)], check=True, capture_output=True)
        os.replace(partial, library)


def compiled_plant(params: PlantParams = PlantParams(), *, exact: bool = False, **options) -> Plant:
    """The high-fidelity plant with its equations and their Jacobian in machine code (cached per machine):
    the same numbers as Plant(params), faster (docs/results.md); Plant(params) without a C compiler. `exact`: the
    machine code of MachineCode(exact=True) (training's data)."""
    return Plant(params, compiler=MachineCode(exact=exact), **options)
