"""The local region on the device: rings grown from seeds (one region, a batch), contact queries, the
normals of moved vertices, the region's state and its motion check."""
