"""rl-zoo3's configuration of the residual agent: ``ppo.yml`` and the module ``ppo`` (``--conf-file
ehss_gym.agents.hyperparams.ppo``), both generated from :data:`ehss_gym.agents.specs.AGENTS` by
``python -m ehss_gym.train.zoo`` (a test fails when they drift from the specs)."""
