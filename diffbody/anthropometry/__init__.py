"""Anthropometry: per-segment scaling, ANSUR II measurements as differentiable functions of
the body, the population prior, and solving for the body with given measurements."""

from ._measurements import (
    MEASUREMENT_NAMES as MEASUREMENT_NAMES,
)
from ._measurements import (
    MEASUREMENTS as MEASUREMENTS,
)
from ._measurements import (
    measure as measure,
)
from ._measurements import (
    measurements as measurements,
)
from ._prior import (
    PopulationPrior as PopulationPrior,
)
from ._scale_to import (
    PopulationScaling as PopulationScaling,
)
from ._scale_to import (
    scale_population as scale_population,
)
from ._scale_to import (
    scale_to as scale_to,
)
from ._scale_to import (
    scale_to_percentile as scale_to_percentile,
)
from ._scaling import (
    SCALE_GROUPS as SCALE_GROUPS,
)
from ._scaling import (
    scale_body as scale_body,
)
