"""MLflow's system metrics (CPU, memory, disk, network, GPU as ``system/...`` metrics), on with
``--system-metrics`` (:func:`enable_system_metrics`)."""

from __future__ import annotations

import os

from ..errors import TrackingError

__all__ = ["SYSTEM_METRICS_ENV", "enable_system_metrics", "system_metrics_monitor"]

#: MLflow's own switch for system metrics (CPU, memory, disk, network, GPU every 10 s, as
#: ``system/...`` metrics); ``--system-metrics`` sets it, and child processes inherit it.
SYSTEM_METRICS_ENV = "MLFLOW_ENABLE_SYSTEM_METRICS_LOGGING"


def enable_system_metrics() -> None:
    """Turn MLflow's system metrics on for the runs this process and its children start (what
    ``--system-metrics`` does): CPU, memory, disk, network (and GPU with ``nvidia-ml-py``), sampled
    every 10 s as ``system/...`` metrics, shown on a run's "System metrics" tab."""
    _require_psutil()
    os.environ[SYSTEM_METRICS_ENV] = "true"


def _require_psutil() -> None:
    try:
        import psutil  # noqa: F401  (MLflow's system metrics read the machine through it)
    except ImportError:
        raise TrackingError(
            f"system metrics (--system-metrics, or {SYSTEM_METRICS_ENV}=true) need psutil: pip install psutil"
        ) from None


def system_metrics_monitor(run_id: str, uri: str, *, resume: bool):
    """MLflow's system-metrics thread on run ``run_id``, started, when :data:`SYSTEM_METRICS_ENV`
    is on (MLflow starts it only for runs of its fluent API; these runs are the client's); else None."""
    if os.environ.get(SYSTEM_METRICS_ENV, "").strip().lower() not in ("true", "1"):
        return None
    _require_psutil()
    import logging

    from mlflow.system_metrics.system_metrics_monitor import SystemMetricsMonitor

    logging.getLogger("mlflow.system_metrics").setLevel(logging.WARNING)  # no start/stop chatter
    monitor = SystemMetricsMonitor(run_id, resume_logging=resume, tracking_uri=uri)
    monitor.start()
    return monitor
