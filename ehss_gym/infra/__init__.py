"""Infrastructure, apart from the simulation: running jobs (:mod:`~ehss_gym.infra.execution`: the local and Ray
backends and the content-addressed result store), number formatting for reports (:mod:`~ehss_gym.infra.fmt`) and file
helpers (:mod:`~ehss_gym.infra.util`: atomic writes, output folders). Nothing here imports the rest of the package.
"""
