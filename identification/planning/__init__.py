"""Test planning: which exciter test determines the parameters asked for.

`plan_test(fit_names, ...)` -> `TestPlan` (its `PlannedRecord`s, the Fisher standard
errors each parameter would get: `fisher_std`, `fisher_stds`), `candidate_plans`,
`plan_from_records` (the plan that a set of records is).
"""

from ._plan import PlannedRecord as PlannedRecord
from ._plan import TestPlan as TestPlan
from ._plan import candidate_plans as candidate_plans
from ._plan import fisher_std as fisher_std
from ._plan import fisher_stds as fisher_stds
from ._plan import plan_from_records as plan_from_records
from ._plan import plan_test as plan_test
