"""Training learned controllers with stable-baselines3 (the ``train`` extra): hyperparameters in
rl-baselines3-zoo's format, the run folder, evaluation by the project's metrics, export to NumPy."""
