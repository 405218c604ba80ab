"""The physics and the math, no I/O (docs/architecture.md): numerics/, plant/ (the high-fidelity switch),
reduced/ (the reduced hybrid model and its rails), health/ and diagnosis/, each importing only the rooms
listed before it; params/ holds the shipped weights."""
