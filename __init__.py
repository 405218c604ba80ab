"""railswitch: online model-based diagnosis of railway switches (point machines).

This checkout's top folder is the package `railswitch` (pyproject.toml maps it), so its
rooms import as `railswitch.models`, `railswitch.schemas` and `railswitch.services`;
docs/architecture.md says what lives where.
"""
