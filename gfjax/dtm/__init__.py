"""Digital terrain models from ground points: cell means, TIN fill, GeoTIFF and hillshade; and the
canopy height model over them.

```python
dtm = gfjax.dtm.build(cloud, result.ground, cell_m=1.0, max_edge_m=100.0)
dtm.to_geotiff("dtm.tif"); dtm.to_png("hillshade.png")
gfjax.dtm.mosaic(["a.tif", "b.tif"], "survey.tif")      # DTMs of adjacent files, joined
gfjax.dtm.chm(cloud, result.ground, cell_m=1.0).to_geotiff("chm.tif")   # highest point's height a cell
```
"""
from gfjax.dtm.build import DTM, build, check_options, memory_estimate
from gfjax.dtm.chm import chm
from gfjax.dtm.geotiff import NODATA, mosaic

__all__ = ["DTM", "build", "chm", "check_options", "memory_estimate", "mosaic", "NODATA"]
