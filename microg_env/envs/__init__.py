"""Gymnasium environments over the rig model."""
