"""Differentiable tuning of filter thresholds (SPEC section 7).

```python
import gfjax
from gfjax.tune import Problem, Sample, Settings, fit
samples = [Sample.from_cloud(gfjax.read("labelled.laz"))]
problem = Problem(samples, config=gfjax.smrf.Config(), max_window_m=24.0)
result = fit.fit(problem, Settings(steps=60))       # module `fit`, function `fit`
checked = validate(problem, Settings(), folds=3)    # keep it only where held-out data say so
```
`relax` holds the soft thresholds, `params` the bounded parametrisation and params.json,
`smrf` the relaxed SMRF pipeline, `pmf` the relaxed PMF point test, `csf` CSF's relaxed class
test on cached grid cloths, `methods` what the loop needs of each (`Problem(..., method=methods.PMF)`), `fit` the optax loop, `guard` the
cross-validated test against the defaults.
"""
from gfjax.tune import fit, guard, methods, relax
from gfjax.tune.fit import FitResult, Settings, hard_errors
from gfjax.tune.guard import Validation, validate
from gfjax.tune.params import read_params, write_params
from gfjax.tune.problem import Problem, Sample, block_folds

__all__ = ["relax", "fit", "guard", "methods", "Sample", "Problem", "Settings", "FitResult", "Validation", "fit", "validate",
           "hard_errors", "block_folds", "read_params", "write_params"]
