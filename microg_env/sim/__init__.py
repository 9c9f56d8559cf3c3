"""Simulation core: parameters -> MuJoCo model, the closed-form contact, drop test, ideal references."""
