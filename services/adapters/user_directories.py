"""Where railswitch keeps a user's files: one rule for the compiled-code cache, the trained models and the
switches' baselines (an environment variable of ours, else the XDG base directory, else its default)."""
from __future__ import annotations

import os
from pathlib import Path


def user_directory(override: str, xdg: str, default: tuple[str, ...], *parts: str) -> Path:
    """`$override` when set; else `$xdg` (or `~/<default>`) / railswitch / `parts`. Raises RuntimeError when
    neither is set and there is no home directory."""
    configured = os.environ.get(override)
    if configured:
        return Path(configured)
    base = os.environ.get(xdg) or Path.home().joinpath(*default)
    return Path(base, "railswitch", *parts)
