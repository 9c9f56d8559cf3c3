"""Recorded runs, their metrics, the evaluation harness and figures."""
