"""Contact: signed distances between the body's spheres and to an environment of planes,
spheres, capsules and boxes, the pairs that can touch, contact reports, and the support
polygon of a standing body (docs/design.md, section 10)."""

from ._distances import (
    closest_pair_gaps as closest_pair_gaps,
)
from ._distances import (
    environment_gaps as environment_gaps,
)
from ._distances import (
    sphere_distances as sphere_distances,
)
from ._environment import (
    Environment as Environment,
)
from ._environment import (
    sphere_environment_distances as sphere_environment_distances,
)
from ._pairs import (
    SpherePairs as SpherePairs,
)
from ._pairs import (
    sphere_pairs as sphere_pairs,
)
from ._report import (
    Contact as Contact,
)
from ._report import (
    ContactReport as ContactReport,
)
from ._report import (
    contact_report as contact_report,
)
from ._support import (
    sole_spheres as sole_spheres,
)
from ._support import (
    support_edges as support_edges,
)
