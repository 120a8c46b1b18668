"""Passes over a whole recording: ``tune`` (noise levels from the data's likelihood,
:mod:`.tuning`) and the RTS smoother (:mod:`.smoother`)."""
