"""Shared geometry under every stage: cameras and pixels, mesh normals, rotations, rigid and similarity alignment,
planes.

Each function works on NumPy arrays, and where a stage needs it on torch tensors too, with the shapes in its
docstring; none imports torch at load time (the loader checks a photo before torch is imported).

- ``camera``: pixel-centre rescaling, intrinsics of a crop or a resize, pinhole projection;
- ``mesh``: face and area-weighted vertex normals;
- ``rotations``: cross-product (skew) matrices, the rotation turning one direction onto another;
- ``alignment``: least-squares similarity / rigid transforms between corresponding points (Umeyama 1991);
- ``plane``: a plane through most of a point set (trimmed least squares) and a frame on it facing the camera.
"""
