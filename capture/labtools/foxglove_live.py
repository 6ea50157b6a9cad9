"""The live session in Foxglove: a WebSocket server (Foxglove's own SDK) with the
recording's topics, schemas and encoders.

A session tap (a Sink, Session.add_tap): the session hands it what it hands the recorder;
a worker thread encodes with the recorder's own encoders (capture.recording.encode) and
publishes, so a live view and a recording of the same moment are the same messages. Only
topics a client subscribes to are encoded; depth, images and clouds go out at most
`image_hz` times a second. The queue between the session and the worker is bounded: a
slow client costs dropped live messages (counted), never a frame of the session.

The SDK's log lines (Python's `foxglove` loggers) quote what clients send: they pass
through `ClientLog`, which escapes them and counts repeats (capture.labtools.safetext) before they
reach walkcap's log, the terminal or the UI's log file.
"""

from __future__ import annotations

import collections
import functools
import logging
import threading
import time
from pathlib import Path

from capture.errors import CaptureError
from capture.labtools.safetext import Repeats, escape, kind_of
from capture.recording import encode as E
from capture.recording import topics as T
from capture.recording.sink import Sink

log = logging.getLogger(__name__)

LAYOUT = Path(__file__).resolve().parent / "layouts" / "walkcap.json"
QUEUE_ITEMS = 256
IMAGE_TOPICS = frozenset({T.DEPTH, T.CONFIDENCE, T.GRAY, T.CLOUD, T.BINARY_IMAGE, T.TF})


class ClientLog(logging.Handler):
    """The SDK's log records, escaped and with repeats counted, as walkcap's own."""

    def __init__(self) -> None:
        super().__init__()
        self.repeats = Repeats()

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            show, n = self.repeats.check(f"{record.levelno} {kind_of(text)}")
            if show:
                count = f" ({n} like it so far)" if n > self.repeats.burst else ""
                log.log(record.levelno, "Foxglove live view: %s%s", escape(text), count)
        except Exception:
            self.handleError(record)


_client_log_lock = threading.Lock()


def client_log() -> ClientLog:
    """The one ClientLog, in place of the `foxglove` loggers' propagation (set up once)."""
    with _client_log_lock:
        sdk = logging.getLogger("foxglove")
        for handler in sdk.handlers:
            if isinstance(handler, ClientLog):
                return handler
        handler = ClientLog()
        sdk.addHandler(handler)
        sdk.propagate = False  # nothing of it reaches a handler unescaped
        return handler


class _Subscriptions:
    """ServerListener: which topics some client is subscribed to."""

    def __init__(self) -> None:
        self.count: collections.Counter[str] = collections.Counter()
        self.clients: set[int] = set()

    def on_subscribe(self, client, channel) -> None:
        self.count[channel.topic] += 1
        self.clients.add(client.id)

    def on_unsubscribe(self, client, channel) -> None:
        self.count[channel.topic] = max(0, self.count[channel.topic] - 1)


class FoxgloveLive(Sink):
    """A Foxglove WebSocket server publishing the live session; `port=0` picks a free one."""

    def __init__(
        self, host: str = "127.0.0.1", port: int = 8765, image_hz: float = 5.0, name="walkcap"
    ) -> None:
        try:
            import foxglove
        except ImportError as e:
            raise CaptureError(f"Foxglove live view needs foxglove-sdk: {e}") from None
        self.client_log = client_log()
        self._client_seen = self.client_log.repeats.total
        self._client_held = self.client_log.repeats.held_back
        self._context = foxglove.Context()
        self._subscriptions = _Subscriptions()
        try:
            self.server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                server_listener=self._subscriptions,
                context=self._context,
            )
        except Exception as e:  # a port in use: one line, the session goes on without it
            raise CaptureError(f"Foxglove live view: cannot listen on {host}:{port}: {e}") from None
        self.port = self.server.port
        self.channels = {}
        for topic, spec in T.TOPICS.items():
            schema = foxglove.Schema(
                name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data
            )
            self.channels[topic] = foxglove.Channel(
                topic,
                schema=schema,
                message_encoding=spec.message_encoding,
                context=self._context,
                metadata={"description": spec.description},
            )
        self._min_image_s = 1.0 / image_hz if image_hz > 0 else 0.0
        self._next_image = 0.0
        self._next_processed = 0.0
        self._queue: collections.deque = collections.deque(maxlen=QUEUE_ITEMS)
        self._ready = threading.Event()
        self._halt = threading.Event()
        self.published = 0
        self.dropped = 0
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="walkcap-foxglove", daemon=True)
        self._thread.start()

    @property
    def client_messages(self) -> int:
        """The SDK's log lines about clients since this server started (shown or counted)."""
        return self.client_log.repeats.total - self._client_seen

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    def _watched(self, *topics: str) -> bool:
        count = self._subscriptions.count
        return any(count[t] for t in topics)

    def _put(self, encode, *data) -> None:
        """`encode(*data)` for the worker: the session's thread only queues the reference."""
        if len(self._queue) == self._queue.maxlen:
            self.dropped += 1
        self._queue.append(functools.partial(encode, *data))
        self._ready.set()

    # ---- the session's data (Sink) ---------------------------------------------------------

    def write_frame(self, frame, time_ns: int | None = None) -> None:
        if not self._watched(T.DEPTH, T.CONFIDENCE, T.GRAY):
            return
        now = time.monotonic()
        if now < self._next_image:
            return
        self._next_image = now + self._min_image_s
        t = frame.device_time_ns if time_ns is None else time_ns
        self._put(E.encode_depth, frame, t, frame.host_time_ns)

    def write_processed(
        self, frame_index, time_ns, log_time_ns, cloud, image, quaternion, flag
    ) -> None:
        if not self._watched(T.CLOUD, T.BINARY_IMAGE, T.TF, T.PREPROCESS):
            return
        now = time.monotonic()
        if now < self._next_processed:
            return
        self._next_processed = now + self._min_image_s
        self._put(
            E.encode_processed, frame_index, time_ns, log_time_ns, cloud, image, quaternion, flag
        )

    def write_inference(self, frame_index, time_ns, log_time_ns, cnn_probs, fused) -> None:
        if self._watched(T.CNN, T.FUSED):
            self._put(E.encode_inference, frame_index, time_ns, log_time_ns, cnn_probs, fused)

    def write_features(self, frame_index, time_ns, features) -> None:
        if self._watched(T.FEATURES):
            self._put(E.encode_features, frame_index, time_ns, time_ns, features)

    def write_truth(self, frame_index, time_ns, truth) -> None:
        if self._watched(T.TRUTH):
            self._put(E.encode_truth, frame_index, time_ns, time_ns, truth)

    def write_gait(self, event, log_time_ns=None) -> None:
        if self._watched(T.gait_topic(event)):
            self._put(E.encode_gait, event, log_time_ns)

    def write_imu(self, sample) -> None:
        if self._watched(T.IMU):
            self._put(E.encode_imu, sample)

    def write_label(self, time_ns: int, mode: str, source: str) -> None:
        self._put(E.encode_label, time_ns, mode, source)

    def write_event(self, event) -> None:
        self._put(E.encode_event, event)

    # ---- the worker ------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._halt.is_set():
            if not self._queue:
                self._ready.wait(0.2)
                self._ready.clear()
                continue
            encode = self._queue.popleft()
            try:
                for m in encode():
                    # Foxglove shows log time: the sample time on the session clock.
                    self.channels[m.topic].log(m.data, log_time=int(m.publish_time))
                    self.published += 1
            except Exception as e:  # a bad item costs a live message, never the session
                self.errors += 1
                if self.errors == 1:
                    log.warning("Foxglove live view: %s", escape(str(e)))

    def close(self) -> None:
        self._halt.set()
        self._ready.set()
        self._thread.join(timeout=2.0)
        try:
            self.server.stop()
        except Exception as e:
            log.warning("Foxglove live view: stop: %s", escape(str(e)))
        held = self.client_log.repeats.held_back - self._client_held
        if held:
            log.warning(
                "Foxglove live view: %d of %d log lines about clients not shown (repeats)",
                held,
                self.client_messages,
            )
