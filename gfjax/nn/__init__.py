"""Neural-network building blocks in JAX and equinox (`gfjax.nn.sparse`: sparse 3D convolution)."""
