"""The published trained policies, installed as the package data ``cloth_gym.models``: one run
directory per policy and ``MANIFEST.json`` listing them. Load one with
:func:`cloth_gym.agents.published.load_published`."""
