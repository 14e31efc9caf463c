"""3D reconstruction from a latent image code (thesis 3.3, 3.4): the Inception Spiral Module mesh decoder.

- ``hierarchy``: the template's QSLIM levels, up/down-sampling matrices and spiral sequences (cached ``.npz``);
- ``spiral``: ``SpiralConv`` and ``InceptionSpiralModule`` on (B, V, C) vertex features;
- ``decoder``: ``SpiralDecoder`` (thesis Figure 3.6): latent (B, C) -> vertices (B, 4002, 3), mm, camera frame;
- ``edgeconv``: the EdgeConv (DGCNN) point-cloud baseline and ``chamfer_distance``;
- ``losses``: L1 + edge length + 0.1 x normal (the thesis), and a scale-free Laplacian structure term;
- ``joints``: 18 joints from mesh vertices by the template's vertex groups, midfoot-aligned joint error.

See ``docs/recon.md``.
"""
