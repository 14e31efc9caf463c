"""The foot model: PCA shape, 18-joint kinematic skeleton, skinning (a pure function of its parameters)."""
