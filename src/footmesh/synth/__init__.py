"""Synthetic foot images with full ground truth (issue 4; thesis 3.5.3): ``footmesh synth``.

- ``scene``: what a sample shows, drawn from ``np.random.default_rng([seed, index])``;
- ``raster``: the numpy z-buffer rasteriser; ``textures``: procedural floors and reference objects;
- ``render``: ``Renderer(config).render(seed, index) -> dict`` of image, depth and labels;
- ``dataset``: chunk files written by shards, and ``SynthDataset`` (a torch ``Dataset``) over a folder;
- ``preview``: contact sheets. See ``docs/synth.md``.
"""
