"""``python -m train.ppo [ehss train arguments]``: train residual PPO or pure PPO (see ehss_gym/rl/train.py)."""

import sys

from ehss_gym.rl.train import main

if __name__ == "__main__":
    sys.exit(main())
