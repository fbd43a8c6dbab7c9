"""The tiling layer: a cloud cut into buffered tiles, padded into batches, a method driven over them.

Above `gfjax.io` (which reads and writes clouds) and below the methods. `tiles` (`Tiling`,
`Lattice`, `split`, `merge`), `buckets` (the capacities and raster sides every method's
programs are padded to), `batches` (tiles padded for `jax.vmap`), `driver` (a batch program
run over a cloud's tiles; a cloud of groups far apart filtered group by group), `mosaic`
(tile cores into whole-cloud rasters), `checks` (the checks at the top of every method's
`filter`), `groups` (groups of points far apart). `gfjax.Tiling` is `tiles.Tiling`.

Import the modules themselves (`from gfjax.tiling import tiles`): this package face imports
nothing, so `gfjax.tiling.buckets` stays free of numpy, laspy and JAX.
"""
