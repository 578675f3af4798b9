"""Live RGB-D frames for a consumer slower than the camera, with every frame recorded.

A LiveSource runs two threads beside its consumer (the thread that iterates `latest()`):

- capture: pulls every frame from the camera iterator as fast as the camera delivers, keeps the
  newest one for the consumer, and puts each frame into a bounded queue for the writer. It never
  waits for the consumer or for the writer, so the camera's own buffers never fill up.
- writer: takes frames from the queue in order and appends them to the MCAP recording with a
  RecordingWriter, so compression and disk writes never stall the capture.

The consumer gets the newest frame it has not seen yet and jumps over older ones (live sensing
must keep up with the present), counting them. The recording comes first: while the writer lags
far behind, the consumer is held back and leaves the writer the CPU. An error in either thread
(a CameraError from the camera, a RecordingError from the writer) is raised again, as the same
exception object, in the consumer. Closing the source stops the capture, lets the writer drain
the queue and finishes the recording, so the MCAP holds every captured frame (less `dropped`).
"""

from __future__ import annotations

import queue
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.camera.rectification import rectified
from softforce_cli.io.atomic import check_writable
from softforce_cli.io.mcap_writer import RecordingWriter

# Frames the writer may lag behind the capture before a frame is dropped from the recording.
# Writing a 640x480 RealSense-like frame takes 16-18 ms on this 2-core machine (12 ms of it
# zstd), 30-55 ms while a consumer keeps both cores busy: then the writer falls behind 30 fps
# until the consumer is held back (HOLD_FRACTION). Measured, 10 s at 30 fps of noisy 640x480
# frames with a consumer busy 30 ms per frame (numpy or pure Python) and the machine's load at
# 6: the queue peaks at 32-34 frames, the hold level, and nothing is dropped; without the hold
# it overflowed 64 frames. A consumer that sleeps instead leaves the queue at 1 frame. 64 frames
# keep twice the hold level as a margin (2.1 s at 30 fps) and take 96 MB at 640x480 (1.5 MB a
# frame), a tenth of sensing's 1 GB budget.
QUEUE_FRAMES = 64

# Python hands the GIL between busy threads every 5 ms by default. The writer releases it about
# ten times per frame (zstd, crc32, file writes) and waits up to that long to take it back from
# a busy consumer each time; 1 ms cuts that wait. Measured with a pure-Python consumer busy
# 30 ms per frame: writing took 39 -> 17 ms per frame, and over 10 s at 30 fps the consumer was
# held back 0.5-3 s (queue at the hold level, 32) at 5 ms, never at 1 ms (queue peak 5-10).
# Set while a source runs, restored when the last one closes.
SWITCH_INTERVAL_S = 0.001

# The recording comes before the consumer: while the writer lags by HOLD_FRACTION of the queue
# or more, latest() holds the consumer back (it skips frames meanwhile, as it would anyway) until
# the lag is down to RELEASE_FRACTION, so that a consumer busy on both cores leaves the writer
# the CPU it needs instead of making it overflow the queue.
HOLD_FRACTION = 0.5
RELEASE_FRACTION = 0.25

POLL_S = 0.1  # how often waiting threads look for errors (waits are woken at once otherwise)

_END = object()  # put in the queue after the last frame


@dataclass(frozen=True)
class LiveStats:
    """Frame counts of a LiveSource, at one instant.

    captured            : frames pulled from the camera iterator.
    delivered           : frames `latest()` gave to the consumer.
    skipped_by_consumer : frames `latest()` jumped over to give a newer one (the consumer was
                          busy, or held back, when they arrived); delivered + skipped ==
                          captured once the consumer has caught up with the end of the capture.
    recorded            : frames written to the recording (0 without one).
    dropped             : frames left out of the recording because the queue was full.
    queue_peak          : the most frames waiting in the queue at once (of `queue_frames`).
    consumer_held_s     : seconds latest() held the consumer back for a lagging writer.
    """

    captured: int
    delivered: int
    skipped_by_consumer: int
    recorded: int
    dropped: int
    queue_peak: int
    consumer_held_s: float


class LiveSource:
    """Capture `frames` on a thread, record each of them on another, serve the newest one.

    frames       : the camera iterator, e.g. iter_live_frames(settings); it is consumed and
                   closed on the capture thread (a generator's cleanup, such as stopping the
                   RealSense pipeline, runs there). It must yield frames that own their arrays
                   (as realsense.py's do), since they outlive the next ones.
    record_to    : MCAP recording to write every captured frame to; None records nothing.
    force        : overwrite `record_to` if it exists (else OutputExistsError, raised here,
                   before the camera starts).
    queue_frames : frames the writer may lag behind before one is dropped (see QUEUE_FRAMES).
    metadata     : extra key/value strings for the recording's `softforce` metadata record.

    A context manager: entering starts both threads, leaving stops the capture, drains the queue
    and finishes the recording (also on an exception or KeyboardInterrupt in the with block).
    A recording without any frame is not written. Use it from one consumer thread.
    """

    def __init__(
        self,
        frames: Iterator[RgbdFrame],
        record_to: Path | None = None,
        force: bool = False,
        queue_frames: int = QUEUE_FRAMES,
        *,
        metadata: Mapping[str, str] | None = None,
    ) -> None:
        if queue_frames < 1:
            raise ValueError(f"queue_frames must be at least 1; got {queue_frames}")
        self.record_to = None if record_to is None else Path(record_to)
        if self.record_to is not None:
            check_writable(self.record_to, force)
        self._frames = frames
        self._force = force
        self._metadata = metadata
        self._queue: queue.Queue = queue.Queue(maxsize=queue_frames)
        self._changed = threading.Condition()  # guards the fields below; notified on any change
        self._newest: RgbdFrame | None = None
        self._captured = self._delivered = self._skipped = self._dropped = self._peak = 0
        self._capture_done = False
        self._hold_above = max(1, round(HOLD_FRACTION * queue_frames))
        self._release_at = min(self._hold_above - 1, round(RELEASE_FRACTION * queue_frames))
        self._holding = False
        self._held_s = 0.0
        self._errors: list[BaseException] = []
        self._errors_raised = 0  # errors are raised in the consumer in order, each once
        self._stop = threading.Event()
        self._writer: RecordingWriter | None = None
        self._threads: list[threading.Thread] = []
        self._state = "new"  # -> "running" -> "closed"

    @property
    def stats(self) -> LiveStats:
        """Counts so far (final once the source is closed)."""
        with self._changed:
            return LiveStats(
                captured=self._captured,
                delivered=self._delivered,
                skipped_by_consumer=self._skipped,
                recorded=self._writer.frames_written if self._writer is not None else 0,
                dropped=self._dropped,
                queue_peak=self._peak,
                consumer_held_s=self._held_s,
            )

    @property
    def closed(self) -> bool:
        """True once close() has stopped both threads and finished the recording."""
        return self._state == "closed"

    def latest(self) -> Iterator[RgbdFrame]:
        """Yield the newest frame not yet yielded, waiting for one; skip (and count) older ones.

        Ends when the camera iterator has ended and its last frame was yielded. An error of the
        capture or writer thread is raised at the next request after it happened. Waits longer
        while the writer lags far behind (see HOLD_FRACTION). Frames through a distorting lens
        come rectified (camera.rectification); the recording keeps them as captured, with
        the lens in its camera_info.
        """
        self._check_running()
        seen = 0  # frames captured up to the one last yielded
        while True:
            with self._changed:
                while True:
                    self._raise_thread_error()
                    holding = self._hold_for_writer()
                    if self._captured > seen and not holding:
                        break
                    if self._capture_done and self._captured == seen:
                        return
                    start = time.monotonic()
                    self._changed.wait(POLL_S)
                    if holding:
                        self._held_s += time.monotonic() - start
                frame = self._newest
                self._skipped += self._captured - seen - 1
                self._delivered += 1
                seen = self._captured
            yield rectified(frame)

    def wait(self) -> None:
        """Block until the camera iterator ends (every frame is then captured, not necessarily
        written: close() waits for that); raise an error of either thread."""
        self._check_running()
        with self._changed:
            while not self._capture_done:
                self._raise_thread_error()
                self._changed.wait(POLL_S)
            self._raise_thread_error()

    def close(self) -> None:
        """Stop the capture, write every queued frame, finish the recording, join the threads.

        Raises an error of either thread that the consumer has not seen yet (e.g. the disk
        filled up while the last frames were written). The capture stops after the frame the
        camera is delivering; a stalled camera holds it until the camera iterator times out.
        A second KeyboardInterrupt while the queue drains abandons the recording's finish: its
        temporary file keeps the frames written so far (see docs/recordings.md).
        """
        self._stop.set()
        for thread in self._threads:
            thread.join()  # at once when already joined
        if self._state == "running":
            _restore_switch_interval()
        self._state = "closed"
        with self._changed:
            self._raise_thread_error()

    def __enter__(self) -> LiveSource:
        if self._state != "new":
            raise RuntimeError("a LiveSource can be started only once")
        if self.record_to is not None:
            self._writer = RecordingWriter(
                self.record_to, force=self._force, metadata=self._metadata
            )
            self._threads.append(
                threading.Thread(target=self._write, args=(self._writer,), name="live-writer")
            )
        self._threads.append(threading.Thread(target=self._capture, name="live-capture"))
        _lower_switch_interval()
        self._state = "running"
        for thread in self._threads:
            thread.daemon = True  # a camera that never returns must not keep the process alive
            thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _check_running(self) -> None:
        if self._state == "new":
            raise RuntimeError("start the LiveSource first: `with LiveSource(...) as source:`")

    def _hold_for_writer(self) -> bool:
        """Whether the consumer must wait for the writer to catch up (call holding the lock)."""
        if self._writer is None or self._capture_done:
            return False
        waiting = self._queue.qsize()
        if waiting >= self._hold_above:
            self._holding = True
        elif waiting <= self._release_at:
            self._holding = False
        return self._holding

    def _raise_thread_error(self) -> None:
        """Raise the oldest error of either thread not raised yet (call holding the lock)."""
        if self._errors_raised < len(self._errors):
            self._errors_raised += 1
            raise self._errors[self._errors_raised - 1]

    def _fail(self, error: BaseException) -> None:
        with self._changed:
            self._errors.append(error)
            self._changed.notify_all()

    def _capture(self) -> None:
        """Capture thread: every frame to the consumer's slot and to the writer's queue."""
        try:
            for frame in self._frames:
                with self._changed:
                    self._newest = frame
                    self._captured += 1
                    self._changed.notify_all()
                if self._writer is not None:
                    self._enqueue(frame)
                if self._stop.is_set():
                    break
        except BaseException as error:  # raised again in the consumer
            self._fail(error)
        finally:
            self._close_frames()
            with self._changed:
                self._capture_done = True
                self._changed.notify_all()
            if self._writer is not None:
                self._queue.put(_END)  # waits for room: the writer always drains to _END

    def _enqueue(self, frame: RgbdFrame) -> None:
        try:
            self._queue.put_nowait(frame)
        except queue.Full:
            with self._changed:
                self._dropped += 1
            return
        waiting = self._queue.qsize()
        with self._changed:
            self._peak = max(self._peak, waiting)

    def _close_frames(self) -> None:
        close = getattr(self._frames, "close", None)
        if callable(close):
            try:
                close()
            except BaseException as error:  # raised again in the consumer
                self._fail(error)

    def _write(self, writer: RecordingWriter) -> None:
        """Writer thread: append queued frames until _END, then finish the recording.

        After a failed write the recording is finished at once with the frames before it, and
        the rest of the queue is discarded (the consumer gets the error).
        """
        failed = False
        while (frame := self._queue.get()) is not _END:
            if failed:
                continue
            try:
                writer.write_frame(frame)
            except BaseException as error:  # raised again in the consumer
                self._fail(error)
                failed = True
                self._finish_recording(writer)
            if self._holding:
                with self._changed:
                    self._changed.notify_all()  # the held consumer checks the lag again
        if not failed:
            self._finish_recording(writer)

    def _finish_recording(self, writer: RecordingWriter) -> None:
        """Rename the recording onto its path if it holds a frame; else delete it."""
        try:
            if writer.frames_written > 0:
                writer.close()
            else:
                writer.abort()
        except BaseException as error:  # raised again in the consumer
            self._fail(error)


@dataclass(frozen=True)
class LiveRecording:
    """What record_live did: the recording at `path`, its counts, `interrupted` by Ctrl-C."""

    path: Path
    stats: LiveStats
    interrupted: bool = False

    @property
    def frames(self) -> int:
        """Frames written to `path` (0: nothing was written)."""
        return self.stats.recorded


def record_live(
    frames: Iterator[RgbdFrame],
    path: Path,
    *,
    force: bool = False,
    metadata: Mapping[str, str] | None = None,
    stop_on_interrupt: bool = False,
    queue_frames: int = QUEUE_FRAMES,
) -> LiveRecording:
    """Record every frame of a camera iterator to the MCAP `path`, writing off the capture thread.

    Returns when `frames` ends; errors as LiveSource. A KeyboardInterrupt (Ctrl-C, or raised by
    `frames`) ends the recording like the end of `frames` when `stop_on_interrupt` is set and the
    recording could be finished; the result then says `interrupted`.
    """
    source = LiveSource(frames, path, force, queue_frames, metadata=metadata)
    try:
        with source:
            source.wait()
    except KeyboardInterrupt:
        if not stop_on_interrupt or not source.closed:
            raise
        return LiveRecording(Path(path), source.stats, interrupted=True)
    return LiveRecording(Path(path), source.stats)


_switch_users = 0  # LiveSources running; the interval is restored when the last one closes
_switch_default = sys.getswitchinterval()
_switch_lock = threading.Lock()


def _lower_switch_interval() -> None:
    global _switch_users, _switch_default
    with _switch_lock:
        if _switch_users == 0:
            _switch_default = sys.getswitchinterval()
            sys.setswitchinterval(min(_switch_default, SWITCH_INTERVAL_S))
        _switch_users += 1


def _restore_switch_interval() -> None:
    global _switch_users
    with _switch_lock:
        _switch_users -= 1
        if _switch_users == 0:
            sys.setswitchinterval(_switch_default)
