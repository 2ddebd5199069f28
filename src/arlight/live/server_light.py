"""Light from the light server (``arlight serve-light``) in a live run.

The server publishes :class:`~arlight.nearfield.state.NearFieldLight` states — virtual area
lights and per-object SH indirect light (Rohmer et al. 2015) — which the ``nearfield``
method renders. :class:`ServerLight` prepares ``nearfield`` for the job's world once with an
empty light (:class:`arlight.methods.nearfield.NearFieldClient`: no capture pipeline of its
own) and installs it as the job's preparation; before each frame it reads the client's
newest state **once** and, when it is a new one, installs the prepared state with that
light (:func:`arlight.methods.nearfield.with_light`,
:func:`arlight.sequence.job.install_prepared`), so the frame renders through the same
``render_frame`` as every other. A state whose SH blocks do not match the world's virtual
objects is skipped (counted); a lost server keeps the last light.
"""

from __future__ import annotations

from typing import Any

from arlight.errors import InputError
from arlight.sequence.job import SequenceJob, install_prepared

METHOD = "nearfield"


class ServerLight:
    """Applies a light client's newest state to ``job`` before each frame (see the module
    docstring). ``client``: anything with a ``latest`` NearFieldLight (or None)."""

    def __init__(self, job: SequenceJob, client: Any) -> None:
        from arlight.methods.nearfield import NearFieldClient

        if job.method != METHOD:
            raise InputError(f"the light server's states light the {METHOD} method; got "
                             f"{job.method!r}", field="--method")
        self.job, self.client = job, client
        self.nf = NearFieldClient(job.world, job.settings.options, job.settings)
        self.n_objects = len(job.world.virtual_shapes)
        self.current = None
        self.updates = 0
        self.skipped = 0
        install_prepared(job, self.nf.method, self.nf.state)

    def __call__(self) -> bool:
        """Install the client's newest state if it is new; True when one was installed."""
        from arlight.methods.nearfield import with_light

        newest = self.client.latest
        if newest is None or newest is self.current:
            return False
        if newest.n_objects != self.n_objects:
            self.skipped += 1
            self.current = newest
            return False
        install_prepared(self.job, self.nf.method, with_light(self.nf.state, newest))
        self.current = newest
        self.updates += 1
        return True


__all__ = ["METHOD", "ServerLight"]
