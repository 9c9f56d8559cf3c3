"""Experiments built on :mod:`microg_env.rollout`: the paired controller comparison, PID tuning,
campaign files run on Ray with their Parquet store, and the design studies' pages."""
