"""The type checker the test run installs on gfjax (`conftest.py`): beartype, with ints
accepted where a float is annotated (PEP 484's numeric tower)."""
import beartype

checker = beartype.beartype(conf=beartype.BeartypeConf(is_pep484_tower=True))
