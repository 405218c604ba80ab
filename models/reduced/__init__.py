"""The reduced hybrid switch model in CasADi, its three rail representations (poly, nn, causal), their training
from the plant and their validation against it."""
