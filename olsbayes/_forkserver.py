"""What the process pool's fork server imports once, before it forks any worker.

Workers of ``executor="processes"`` fork from one server process per study
process; whatever the server has imported they start with, instead of each
importing numpy, scipy and the package anew.  The compiled kernels' modules are
imported too (their machine code loads from numba's cache on first use).
"""

from __future__ import annotations

import olsbayes  # noqa: F401  (the package, with numpy, scipy)
import olsbayes.ml._numba.escalate  # noqa: F401
import olsbayes.ml._numba.exact  # noqa: F401
import olsbayes.ml._numba.fit  # noqa: F401
import olsbayes.ml._numba.lm  # noqa: F401
import olsbayes.ml._numba.refine  # noqa: F401
import olsbayes.ml._numba.rivals  # noqa: F401
import olsbayes.ml._numba.search  # noqa: F401
import olsbayes.ml._numba.tuples  # noqa: F401
import olsbayes.ml.fast  # noqa: F401
import olsbayes.studies._work  # noqa: F401
import olsbayes.studies.estimators  # noqa: F401
import olsbayes.studies.trials  # noqa: F401
