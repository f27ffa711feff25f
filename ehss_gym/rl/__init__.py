"""Learned policies for EHSSTracking-v0: the agents (:mod:`.agents`), the training script (:mod:`.train`), its
callbacks (:mod:`.callbacks`), run bookkeeping (:mod:`.runs`) and the held-out evaluation used during training
(:mod:`.heldout`). The top-level ``agents`` and ``train`` folders of the repository are thin entry points to these.
"""
