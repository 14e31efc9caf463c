"""Photo containers beyond what Pillow reads alone, and what phones store inside them.

- ``heif``: HEIC / HEIF photos (pillow-heif) and their embedded depth image (iPhone);
- ``android``: depth maps in Android JPEGs (Dynamic Depth 1.0, GDepth XMP);
- ``camera``: intrinsics files from real tools (K.json, OpenCV calibration YAML / JSON / XML, ARKit);
- ``embedded``: what an embedded depth map means, turned into millimetres aligned with the photo.

Adding a container = one reader here returning an ``embedded.EmbeddedDepth``, and one line in
``footmesh.load.EMBEDDED_DEPTH_READERS``.
"""
