"""The service layer: the pipeline (functional core), stream requests, statistics, the daemon loop.

:class:`~mavahrs.service.pipeline.Pipeline` is imported lazily by callers
(``from mavahrs.service.pipeline import Pipeline``) so that importing this
package stays cheap.
"""

from __future__ import annotations

__all__ = ["pipeline", "stream_requests", "stats"]
