"""``pano4d train --serve``: the Gaussians in the browser while they train.

How it fits together:

1. Before training starts, ``serving(host, port)`` checks that nothing listens on the port
   (a port in use is the user's to fix: one ``error:`` line, exit 2) and opens a
   ``LiveView``: a viser server there, the viewer ``pano4d serve`` uses
   (``pano4d.web``), with a status line on the page.
2. ``run_train(cfg, on_snapshot=view.show)`` hands the view a
   ``lift.pipeline.SceneSnapshot`` whenever the static or the dynamic stage reads its
   Gaussians back anyway: at every checkpoint (``--checkpoint-every`` steps) and at the end
   of each optimisation. Nothing is read from the device for the view, so a training step
   costs what it costs without it.
3. ``show`` only keeps the snapshot; a thread of the view's own converts the latest one to
   viser's splats and sends it, and only while a browser is connected.
4. When training ends (done, failed or interrupted) ``serving`` stops the server.

The page shows the static set and, in the dynamic stage, one node per timestamp: the sets
trained so far and the one in training (or the spacetime set evaluated at each integer
timestamp), with a time slider once there is more than one, and a status line (the
optimisation, its step, the Gaussians shown). As ``pano4d serve``, it draws each
Gaussian's view-independent colour, classic: a scene trained antialiased is sent baked
at its training views' pixel density (``share_formats.bake_antialiasing``).
"""

from __future__ import annotations

import contextlib
import errno
import io
import socket
import threading
from collections.abc import Iterator
from typing import Any

from pano4d.errors import InputError
from pano4d.gaussians import Gaussians
from pano4d.lift.pipeline import SceneSnapshot
from pano4d.share_formats import bake_antialiasing
from pano4d.spacetime import SpacetimeGaussians
from pano4d.web import set_initial_camera, splat_arrays, start_camera, viser_module

WAITING = "**training**: the Gaussians appear at the static stage's first checkpoint"
VIEWPOINT = (0.0, 0.0, 0.0)  # the panorama's, where every training view looks out from


def check_port(host: str, port: int) -> None:
    """InputError unless a server could listen on ``host:port`` now. viser itself would
    move to the next free port without a word, and the user would open the wrong page."""
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as e:
        raise InputError(f"--host {host}: not an address to listen on ({e.strerror})") from e
    for family, kind, protocol, _, address in addresses:
        with socket.socket(family, kind, protocol) as probe:
            # As the server will: a port a finished run left in TIME_WAIT is free.
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind(address)
            except OSError as e:
                if e.errno == errno.EADDRINUSE:
                    raise InputError(port_in_use(host, port)) from e
                raise InputError(
                    f"--host {host} --port {port}: cannot listen there ({e.strerror or e})"
                ) from e


def port_in_use(host: str, port: int) -> str:
    return (
        f"--port {port}: {host}:{port} is already in use (another pano4d serve or train "
        f"--serve?); choose another --port"
    )


class LiveView:
    """A viser server showing the snapshots ``show`` is given (module docstring)."""

    def __init__(self, host: str, port: int) -> None:
        viser = viser_module()
        # viser prints its banner to stdout whatever `verbose` says: keep it out of the run's.
        with contextlib.redirect_stdout(io.StringIO()):
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if self.server.get_port() != port:  # taken since check_port: viser moved on
            self._stop_server()
            raise InputError(port_in_use(host, port))
        set_initial_camera(self.server, start_camera({"camera": {"position": VIEWPOINT}}))
        self.server.scene.set_up_direction("+z")
        self.server.gui.configure_theme(control_layout="floating", show_share_button=False)
        self.status = self.server.gui.add_markdown(WAITING)
        self.slider: Any = None  # the time slider, once there is more than one timestamp
        # The sets on the page: the objects themselves, so a set already sent (the static
        # set, a finished timestamp's) is known by identity and not sent again (None: a
        # spacetime set's evaluation, new at every snapshot, not worth its memory).
        self.static_shown: Gaussians | None = None
        self.timestamps_shown: list[Gaussians | None] = []
        self.dynamic_nodes: list[Any] = []
        # Held while the nodes change: the slider's callback (viser's threads, or this
        # view's own when it moves the slider) shows and hides them.
        self.nodes_lock = threading.RLock()
        # Why a thread, and only the latest snapshot: converting a set (the antialiasing
        # bake, covariances, colours) and viser's serialising take seconds for a balanced
        # scene (200k Gaussians: 4.8 s on this loaded 2-core CPU, 3–4 balanced steps); on
        # the training thread they would stall it at every checkpoint. A snapshot still
        # waiting when a newer one comes is dropped: the page only ever needs the latest
        # scene, and a slow browser or sender never holds training up. Nothing is converted
        # while no browser is connected (one that connects gets the latest snapshot at once).
        self.wake = threading.Condition()
        self.pending: SceneSnapshot | None = None
        self.closing = False
        self.failure: BaseException | None = None  # what stopped the sender (raise_failure)
        self.server.on_client_connect(lambda _client: self._notify())
        self.sender = threading.Thread(target=self._send_latest, name="live view", daemon=True)
        self.sender.start()

    # --- the training thread's side -----------------------------------------------------------
    def show(self, snapshot: SceneSnapshot) -> None:
        """Keep ``snapshot`` to be sent (``run_train``'s ``on_snapshot``); returns at once."""
        with self.wake:
            self.pending = snapshot
            self.wake.notify()

    def close(self) -> None:
        """Stop the sender and the server; the page then says it lost the connection."""
        with self.wake:
            self.closing = True
            self.wake.notify()
        self.sender.join()
        self._stop_server()

    def raise_failure(self) -> None:
        """Raise what stopped the sender, if anything did (a bug: the page stopped
        following the training)."""
        if self.failure is not None:
            raise RuntimeError(f"the live view stopped: {self.failure}") from self.failure

    def _stop_server(self) -> None:
        with contextlib.redirect_stdout(io.StringIO()):  # viser's "Server stopped" line
            self.server.stop()

    # --- the sender thread ----------------------------------------------------------------
    def _notify(self) -> None:
        with self.wake:
            self.wake.notify()

    def _watched(self) -> bool:
        return len(self.server.get_clients()) > 0

    def _send_latest(self) -> None:
        try:
            while True:
                with self.wake:
                    self.wake.wait_for(
                        lambda: self.closing or (self.pending is not None and self._watched())
                    )
                    if self.closing:
                        return
                    snapshot, self.pending = self.pending, None
                assert snapshot is not None
                self._send(snapshot)
        except Exception as e:  # training goes on; the command reports it when it ends
            self.failure = e

    def _send(self, snapshot: SceneSnapshot) -> None:
        """Send what changed since the last snapshot sent: the sets that are new objects."""
        if snapshot.static is not self.static_shown:
            self._add("/static", snapshot.static, snapshot, visible=True)
            self.static_shown = snapshot.static
        sets = timestamp_sets(snapshot)
        evaluated = isinstance(snapshot.dynamic, SpacetimeGaussians)
        with self.nodes_lock:
            self._update_slider(len(sets))
            for t, g in enumerate(sets):
                if t < len(self.timestamps_shown) and self.timestamps_shown[t] is g:
                    continue
                node = self._add(f"/dynamic/t{t:04d}", g, snapshot, visible=t == self._time())
                shown = None if evaluated else g
                if t < len(self.timestamps_shown):
                    self.timestamps_shown[t], self.dynamic_nodes[t] = shown, node
                else:
                    self.timestamps_shown.append(shown)
                    self.dynamic_nodes.append(node)
            self._show_time(self._time())
        self.status.content = status_line(snapshot, sets)

    def _add(self, name: str, g: Gaussians, snapshot: SceneSnapshot, visible: bool) -> Any:
        """Send ``g`` as the node ``name`` (replacing the node of that name), as a viewer that
        draws classic must receive it."""
        if snapshot.antialiased:
            g = bake_antialiasing(g, VIEWPOINT, snapshot.focal_px)
        a = splat_arrays(g)
        return self.server.scene.add_gaussian_splats(
            name, a.centers, a.covariances, a.rgbs, a.opacities, visible=visible
        )

    def _time(self) -> int:
        return 0 if self.slider is None else int(self.slider.value)

    def _update_slider(self, count: int) -> None:
        """A slider over ``count`` timestamps once there is more than one. While it is at the
        last timestamp it follows the one in training as new ones come."""
        if count < 2:
            return
        if self.slider is None:
            self.slider = self.server.gui.add_slider(
                "time index", min=0, max=count - 1, step=1, initial_value=count - 1
            )
            self.slider.on_update(lambda _: self._show_time(self._time()))
        elif count - 1 > self.slider.max:
            following = self._time() == self.slider.max
            self.slider.max = count - 1
            if following:
                self.slider.value = count - 1

    def _show_time(self, t: int) -> None:
        with self.nodes_lock:
            for i, node in enumerate(self.dynamic_nodes):
                node.visible = i == t


def timestamp_sets(snapshot: SceneSnapshot) -> list[Gaussians]:
    """The dynamic set to show at each timestamp so far: none in the static stage, each
    per-timestamp set, or the spacetime set evaluated at each integer timestamp."""
    if snapshot.dynamic is None:
        return []
    if isinstance(snapshot.dynamic, SpacetimeGaussians):
        return [snapshot.dynamic.at(t) for t in range(snapshot.timestamps)]
    return list(snapshot.dynamic)


def status_line(snapshot: SceneSnapshot, sets: list[Gaussians]) -> str:
    """The page's status: the optimisation, its step, the Gaussians shown."""
    shown = f"{len(snapshot.static):,} static Gaussians"
    if isinstance(snapshot.dynamic, SpacetimeGaussians):
        shown += f" + {len(snapshot.dynamic):,} dynamic, one set for {len(sets)} timestamps"
    elif sets:
        shown += f" + {len(sets[-1]):,} dynamic at t={len(sets) - 1}"
    return (
        f"**training {snapshot.optimisation}**: step {snapshot.step} of {snapshot.iterations}"
        f"  \n{shown}"
    )


@contextlib.contextmanager
def serving(host: str, port: int) -> Iterator[LiveView]:
    """A ``LiveView`` on ``host:port`` for the length of the block (InputError if the port
    is in use); the server stops when the block ends, however it ends."""
    check_port(host, port)
    view = LiveView(host, port)
    try:
        yield view
    finally:
        view.close()
    view.raise_failure()  # only once training is done: it must not hide training's own error
