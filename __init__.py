"""railswitch: online model-based diagnosis of railway switches (point machines).

This checkout's top folder is the package `railswitch` (pyproject.toml maps it), so its
rooms import as `railswitch.models`, `railswitch.schemas` and `railswitch.services`;
docs/architecture.md says what lives where.
"""

__all__ = ["DiagnosedThrow", "Diagnoser", "Throw", "make_throw", "read_history", "read_throws", "simulate"]  # from railswitch/api.py


def __getattr__(name: str):
    """The Python API's names (railswitch/api.py), loaded on first use: the services import railswitch's rooms
    without paying for the plant and the estimator."""
    if name in __all__:
        from railswitch import api

        return getattr(api, name)
    raise AttributeError(f"module 'railswitch' has no attribute {name!r}")
