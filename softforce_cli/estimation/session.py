"""A sensing run: frames in, estimates out to the output folder, a summary at the end.

The frame source is any iterator of RgbdFrames (a recording, a live camera); the run is
stopped by the source ending or by Ctrl-C / SIGTERM (KeyboardInterrupt), after which the
files hold every frame processed so far and the summary says the run was interrupted.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Any

from threadpoolctl import threadpool_limits

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.errors import SoftforceError
from softforce_cli.estimation.lookahead import observed_frames
from softforce_cli.estimation.results import FrameEstimate
from softforce_cli.estimation.sensing import ForceSensor
from softforce_cli.estimation.summary import SenseSummary
from softforce_cli.io.sense_files import SenseWriter

FrameCallback = Callable[[FrameEstimate, SenseSummary], None]


@dataclass(frozen=True)
class FrameRange:
    """Frames start <= index < stop of a source (stop None: to the end)."""

    start: int = 0
    stop: int | None = None

    @classmethod
    def parse(cls, text: str | None) -> FrameRange:
        """"A:B", "A:", ":B" or None (every frame); ValueError on anything else."""
        if text is None:
            return cls()
        start, sep, stop = text.partition(":")
        if not sep:
            raise ValueError(f"--frames {text!r}: use START:STOP, e.g. 10:200 or 10:")
        first = int(start) if start.strip() else 0
        last = int(stop) if stop.strip() else None
        if first < 0 or (last is not None and last <= first):
            raise ValueError(f"--frames {text!r}: need 0 <= START < STOP")
        return cls(first, last)

    def select(self, frames: Iterator[RgbdFrame]) -> Iterator[tuple[int, RgbdFrame, float]]:
        """(index, frame, decode_ms) of the frames in range; stops reading past the range."""
        index = 0
        while self.stop is None or index < self.stop:
            began = time.perf_counter()
            frame = next(frames, None)
            if frame is None:
                return
            if index >= self.start:
                yield index, frame, 1e3 * (time.perf_counter() - began)
            index += 1


def run_sensing(
    frames: Iterator[tuple[int, RgbdFrame, float]],
    sensor: ForceSensor,
    folder: Any,
    header: dict[str, Any],
    force: bool = False,
    on_frame: FrameCallback | None = None,
    stop_requested: Callable[[], bool] = lambda: False,
    look_ahead: bool = True,
) -> SenseSummary:
    """Process every frame into `folder`, each frame's vision made while the model settles
    on the one before (estimation.lookahead) unless look_ahead is False. The run ends after
    the frame during which stop_requested() turns true, or at a KeyboardInterrupt, with its
    files complete."""
    summary = SenseSummary()
    writer = SenseWriter(folder, header, force=force)
    stream = observed_frames(frames, sensor) if look_ahead else (
        (*item, None) for item in frames)
    # the look-ahead's two threads keep both cores busy: BLAS threads on top would only
    # contend for them (the reduced P2 model's frames took 2.6 times as long,
    # docs/sensing_studies.md)
    blas = threadpool_limits(limits=1, user_api="blas") if look_ahead else nullcontext()
    began = time.perf_counter()
    with blas:
        try:
            for index, frame, decode_ms, observation in stream:
                estimate = sensor.process(index, frame, observation)
                estimate.timings_ms["decode"] = decode_ms
                summary.add(estimate)
                summary.wall_s = time.perf_counter() - began
                written = time.perf_counter()
                writer.write(estimate, summary.to_dict())
                summary.add_write_ms(1e3 * (time.perf_counter() - written))
                summary.frame_done(time.perf_counter())
                if on_frame is not None:
                    on_frame(estimate, summary)
                if stop_requested():
                    summary.interrupted = True
                    break
        except KeyboardInterrupt:
            summary.interrupted = True
        except SoftforceError as error:
            # the files keep the frames before it and say why they end there
            summary.error = " ".join(str(error).split())
            if summary.frames:
                error.args = (f"{error} (the {summary.frames} frame(s) processed before it "
                              f"are in {writer.folder})",)
            raise
        finally:
            stream.close()  # stops the look-ahead's worker
            summary.wall_s = time.perf_counter() - began
            writer.close(summary.to_dict())
    return summary
