"""``ppo.yml`` as a module, so rl-zoo3 finds it from any directory: ``--conf-file ehss_gym.agents.hyperparams.ppo``."""

from pathlib import Path

import yaml

hyperparams = yaml.safe_load((Path(__file__).with_name("ppo.yml")).read_text())
