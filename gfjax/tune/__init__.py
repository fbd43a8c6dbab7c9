"""Tuning a filter's settings against labelled clouds (SPEC section 7).

```python
import gfjax
tuned = gfjax.tune.tune([gfjax.read("labelled.laz")], "smrf")      # fitted, then guarded
result = gfjax.smrf.filter(cloud, config=tuned.config, params=tuned.params)
tuned.write("params.json")                                         # gfjax filter --params
```
The pieces, for a loop of one's own:
```python
from gfjax.tune import Problem, Sample, Settings, fit
samples = [Sample.from_cloud(gfjax.read("labelled.laz"))]
problem = Problem(samples, config=gfjax.smrf.Config(), max_window_m=24.0)
result = fit.fit(problem, Settings(steps=60))       # module `fit`, function `fit`
checked = validate(problem, Settings(), folds=3)    # keep it only where held-out data say so
```
`run` holds `tune` (what `gfjax tune` calls), `relax` the soft thresholds, `params` the bounded parametrisation and params.json,
`smrf` the relaxed SMRF pipeline, `pmf` the relaxed PMF point test, `csf` CSF's relaxed class
test on cached grid cloths, `tuners` what the loop needs of each method (its own `gfjax.<method>.tuning.TUNER`), `fit` the optax loop, `guard` the
cross-validated test against the defaults.
"""
from gfjax.tune import fit, guard, relax, tuners
from gfjax.tune.fit import FitResult, Settings, hard_errors
from gfjax.tune.guard import Validation, validate
from gfjax.tune.params import read_params, write_params
from gfjax.tune.problem import Problem, Sample, block_folds
from gfjax.tune.run import Tuned, tune

__all__ = ["tune", "Tuned", "relax", "fit", "guard", "tuners", "Sample", "Problem", "Settings", "FitResult", "Validation", "fit", "validate",
           "hard_errors", "block_folds", "read_params", "write_params"]
