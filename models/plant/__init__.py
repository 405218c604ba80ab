"""The high-fidelity switch (plant) and its parts: motor, drive, lock, adjusters, the rail as a beam, the faults
injected into it, the throw's reference profile, the population of switches and the simulation of their throws."""
