"""Compiled inner loops (numba, optional) with their numpy twins."""
