"""Training of footmesh's networks: in-memory synthetic data with augmentation (``data``), a resumable,
distributed training loop (``loop``), and the 2D-cues task (``cues``)."""
