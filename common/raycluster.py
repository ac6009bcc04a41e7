"""Connecting to Ray for `--backend ray` (generation and fusion); the only module that starts Ray.

`address` None: the cluster named by RAY_ADDRESS if that is set ("auto"), else a Ray instance on
this machine, bound to loopback only (127.0.0.1, no dashboard), whose processes end with this
command (common.lifetime.guard_descendants). Usage statistics are always off.
Imported only by the Ray backends: the local pool needs no Ray installed.
"""

from __future__ import annotations

import os
import sys

from .errors import InputError
from .lifetime import guard_descendants


def default_address() -> str | None:
    return "auto" if os.environ.get("RAY_ADDRESS") else None


def connect(address: str | None = None, num_cpus: int | None = None, code_dir=None):
    """ray.init for this process (no-op when already connected); returns the ray module.
    `code_dir` goes onto the workers' PYTHONPATH (the repository, at the same path on every node)."""
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    address = address if address is not None else default_address()
    if address is None or address == "local" or address.rsplit(":", 1)[0] in ("127.0.0.1", "localhost"):
        # a Ray instance on this machine: every Ray address is 127.0.0.1 (Ray would otherwise advertise and
        # connect to the machine's outward address)
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    if "ray" not in sys.modules:
        try:
            import ray  # noqa: F401
        except ImportError:
            raise InputError("--backend ray: Ray is not installed (make setup installs it)") from None
    import ray

    if ray.is_initialized():
        return ray
    env = {"RAY_USAGE_STATS_ENABLED": "0"}
    if code_dir is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(code_dir)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
    kwargs = dict(runtime_env={"env_vars": env}, log_to_driver=False, configure_logging=True,
                  logging_level="WARNING")
    try:
        if address is None or address == "local":
            # a Ray instance of this command: its workers and agents (children of its raylet) end with it
            guard_descendants()
            ray.init(num_cpus=num_cpus, include_dashboard=False, _node_ip_address="127.0.0.1", **kwargs)
        else:
            ray.init(address=address, **kwargs)
    except ConnectionError as exc:
        raise InputError(f"--address: cannot connect to Ray at {address!r} ({exc})") from None
    return ray
