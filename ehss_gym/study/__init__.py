"""The studies: each runs simulations or evaluations and returns what its report (:mod:`ehss_gym.reporting`) renders.

- the reproduction of the paper (``ehss reproduce``): :mod:`~ehss_gym.study.stages` with its settings
  (:mod:`~ehss_gym.study.config`), claims (:mod:`~ehss_gym.study.claims`), rules (:mod:`~ehss_gym.study.rules`)
  and runs (:mod:`~ehss_gym.study.records`);
- the sensor-noise study (``ehss noise``): :mod:`~ehss_gym.study.noise` (:mod:`~ehss_gym.study.noise_config`,
  :mod:`~ehss_gym.study.noise_rules`, :mod:`~ehss_gym.study.bias`);
- the filters' fidelity (``ehss fidelity``): :mod:`~ehss_gym.study.fidelity`;
- the trained agents (``ehss training-report``): :mod:`~ehss_gym.study.training`, and the measurement behind their
  initial exploration noise: :mod:`~ehss_gym.study.exploration`.
"""
