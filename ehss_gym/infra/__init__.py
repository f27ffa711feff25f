"""Infrastructure, apart from the simulation: running jobs (:mod:`~ehss_gym.infra.execution`: the local and Ray
backends and the content-addressed result store), number formatting for reports (:mod:`~ehss_gym.infra.fmt`) and file
helpers (:mod:`~ehss_gym.infra.util`: atomic writes, output folders). Nothing here imports the rest of the package.
"""

import os

# the execution layer's choices, which the command line shows without loading it
BACKENDS = ("local", "ray")
RAY_INSTALL = "pip install 'ehss-gym[ray]'"
DEFAULT_STORE = os.path.join("runs", "jobs")
# set (to anything but empty) to hide the note on stderr while numba compiles the kernels on a cold cache
# (ehss_gym.core.compile_note); the commands' --no-progress sets it
NO_COMPILE_NOTE_ENV = "EHSS_GYM_NO_COMPILE_NOTE"
