"""What a ``divas batch`` job imports, imported once by the process pool's fork server.

On Linux the :class:`~.batch_executors.ProcessExecutor` forks each job's process from a
server that has imported this module, so a job starts with the engine's modules loaded
(about a second of CPU a job otherwise spends on imports) and still runs in a process
of its own. Importing does not initialise Warp: no CUDA context exists before a fork
(``CUDA_VISIBLE_DEVICES`` is set in the job's process, before its first launch).
"""

from __future__ import annotations

import divas_engine.cli.batch_jobs  # noqa: F401
import divas_engine.cli.segment  # noqa: F401
import divas_engine.evaluation.session_scores  # noqa: F401
import divas_engine.io.load  # noqa: F401
import divas_engine.render.surfel_renderer  # noqa: F401
import divas_engine.segment.factory  # noqa: F401
import divas_engine.segment.graph3d  # noqa: F401
import divas_engine.session  # noqa: F401
import divas_engine.views  # noqa: F401
