"""Infrastructure, apart from the simulation: running jobs (:mod:`~ehss_gym.infra.execution`: the local and Ray
backends and the content-addressed result store), number formatting for reports (:mod:`~ehss_gym.infra.fmt`) and file
helpers (:mod:`~ehss_gym.infra.util`: atomic writes, output folders). Nothing here imports the rest of the package.
"""

import os

# the execution layer's choices, which the command line shows without loading it
BACKENDS = ("local", "ray")
RAY_INSTALL = "pip install 'ehss-gym[ray]'"
DEFAULT_STORE = os.path.join("runs", "jobs")
