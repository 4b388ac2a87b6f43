"""The shipped configs, installed as the package data ``cloth_gym.configs``: ``materials/`` (fabric
YAML files) and ``train/`` (rl-baselines3-zoo hyperparameter files). Find them with
``cloth-gym configs`` or :func:`cloth_gym.materials.configs_dir`."""
