"""The vision of the next frame while the FE model settles on this one.

A frame's vision up to its contacts (vision.pipeline.observe_frame: about 15 ms at 640x480)
needs nothing of the FE model but a crop box, and a frame's FE updates (about 25 ms with the
reduced P2 model) need nothing of the next frame, so on two cores they run side by side:
numpy, scipy's KD-trees and open3d spend most of that time in compiled loops that release
the GIL (the two measured 1.8 times faster together than in turn, docs/sensing_studies.md).

A worker thread reads the frames, observes each one in the crop box of the configuration
the sensor last left (one frame old: the box's 40 mm margin is far more than a frame's
motion) and hands them over in order through a short queue; the caller settles the model on
each. The first frame is the caller's to observe, as the sensor learns the robot's colour
on it. Stopping early (Ctrl-C, a closed generator) stops the worker after the frame it is
on; a frame it observed but the caller never took is not processed, as if it had not
arrived.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.estimation.sensing import ForceSensor
from softforce_cli.vision.pipeline import Observation

# Frames observed ahead at most: one keeps both cores busy; more only adds latency.
QUEUE_DEPTH = 1
# How long the worker waits on a full queue before checking whether to stop (s), and how long
# closing waits for it (a live camera's next frame arrives within 1/30 s).
POLL_S = 0.05
JOIN_S = 2.0

Item = tuple[int, RgbdFrame, float]
Observed = tuple[int, RgbdFrame, float, Observation | None]
_END = object()


def observed_frames(frames: Iterator[Item], sensor: ForceSensor) -> Iterator[Observed]:
    """(index, frame, decode_ms, observation) of each (index, frame, decode_ms) of frames, the
    observation made ahead by sensor.observe in a worker thread (None for the first frame,
    which the caller's sensor.process observes itself). Close the generator to stop early."""
    first = next(frames, None)
    if first is None:
        return
    yield (*first, None)
    handoff: queue.Queue = queue.Queue(maxsize=QUEUE_DEPTH)
    stop = threading.Event()

    def offer(item: object) -> None:
        while not stop.is_set():
            try:
                handoff.put(item, timeout=POLL_S)
                return
            except queue.Full:
                continue

    def observe_ahead() -> None:
        try:
            for index, frame, decode_ms in frames:
                offer((index, frame, decode_ms, sensor.observe(frame)))
                if stop.is_set():  # before reading another frame
                    return
        except BaseException as error:  # handed to the caller, which raises it
            offer(error)
            return
        offer(_END)

    worker = threading.Thread(target=observe_ahead, name="softforce-vision", daemon=True)
    worker.start()
    try:
        while True:
            item = handoff.get()
            if item is _END:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join(JOIN_S)
