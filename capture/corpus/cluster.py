"""The Ray cluster behind corpus jobs (capture.corpus.jobs) and training with torch DDP.

`connect("local")` starts a cluster on this machine's cores (no dashboard, Ray's own logs
at errors only); any other address joins a running cluster (`ray start --head` prints
it). `describe` puts a failed task's error in one line.

`train` runs inference.training.train on Ray Train's TorchTrainer: DistributedDataParallel
over gloo, each worker reading the sessions itself.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from capture.errors import CaptureError

log = logging.getLogger(__name__)

LOCAL = "local"
INSTALL_HINT = "--cluster needs Ray: pip install 'walkcap[cluster]'"


class ClusterError(CaptureError):
    """The cluster cannot be reached, or tasks failed (each named on stderr before);
    `results`: every task's result, None for those that failed."""

    def __init__(self, message: str, results: list | None = None) -> None:
        super().__init__(message)
        self.results = results or []


def _ray():
    try:
        import ray
    except ImportError:
        raise ClusterError(INSTALL_HINT) from None
    return ray


@contextmanager
def connect(address: str, num_cpus: int | None = None, worker_logs: bool = True) -> Iterator[dict]:
    """Ray connected for the block: a local cluster started on this machine (`local`,
    `num_cpus` cores, default all) or a running cluster joined at `address`. Yields the
    cluster's resources. Already connected (a test's cluster), the connection is kept.
    `worker_logs`: the workers' log lines shown here (training leaves them out: Ray
    Train's own actors log their every retry)."""
    ray = _ray()
    if ray.is_initialized():
        yield ray.cluster_resources()
        return
    options = {
        "logging_level": logging.ERROR,
        "include_dashboard": False,
        "configure_logging": True,
        # the tasks' own warnings (a damaged chunk, a skipped frame) reach stderr
        "log_to_driver": worker_logs,
    }
    try:
        if address == LOCAL:
            # address "local": a new cluster, never one that RAY_ADDRESS or `ray start`
            # names. Its workers import the walkcap this process runs (they inherit the
            # environment).
            root = str(Path(__file__).resolve().parent.parent)
            path = os.environ.get("PYTHONPATH", "")
            if root not in path.split(os.pathsep):
                os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (root, path) if p)
            ray.init(
                address="local",
                num_cpus=num_cpus or os.cpu_count() or 1,
                # Ray runs its workers at nice 15; here they are this command's own work,
                # not to lose every core to whatever else runs on the machine
                _system_config={"worker_niceness": 0},
                **options,
            )
        else:
            _reachable(address)
            _join(ray, address, options)
    except (ConnectionError, ValueError, RuntimeError, ray.exceptions.RayError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ClusterError(f"cannot join the Ray cluster at {address}: {first}") from None
    try:
        yield ray.cluster_resources()
    finally:
        ray.shutdown()


TOKEN_HINT = (
    "the cluster uses token authentication: set RAY_AUTH_MODE=token here, with the cluster's "
    "token in RAY_AUTH_TOKEN (`ray get-auth-token` on the head node prints it)"
)
JOIN_ATTEMPTS = "10"  # Ray's attempts at the head's GCS, about a second each (Ray: 20)


def _join(ray, address: str, options: dict) -> None:
    """ray.init at a running cluster. Ray's core logs each failed attempt on stderr, 20
    lines for a missing token: they are held back, and a refusal for want of a token
    becomes TOKEN_HINT. Ray never sends this machine's token to an address it is given
    unless RAY_AUTH_MODE=token says so, and neither does walkcap."""
    import tempfile

    os.environ.setdefault("RAY_gcs_server_port_wait_time_s", JOIN_ATTEMPTS)
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            ray.init(address=address, **options)
        except (ConnectionError, RuntimeError, ray.exceptions.RayError) as e:
            held.seek(0)
            said = held.read().decode(errors="replace")
            if "InvalidAuthToken" in said or "Unauthenticated" in said:
                raise ConnectionError(TOKEN_HINT) from None
            if "no authentication token was found" in str(e):
                raise ConnectionError(
                    "RAY_AUTH_MODE=token is set but no token is: give the cluster's token in "
                    "RAY_AUTH_TOKEN (`ray get-auth-token` on the head node prints it)"
                ) from None
            raise
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def _reachable(address: str, timeout_s: float = 3.0) -> None:
    """A head node's host:port answers, or one line now (Ray itself would retry for
    minutes, logging each attempt)."""
    import socket

    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "://" in host:
        return  # "auto", ray:// client addresses: Ray's own rules
    try:
        socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise ClusterError(
            f"no Ray cluster answers at {address} ({e.strerror or e}); start one with "
            "`ray start --head` on the head node and give the address it prints"
        ) from None


def describe(error: BaseException) -> str:
    """A task's error in one line: the user error's own message, else its type and text."""
    from devices.errors import DeviceError
    from inference.errors import InferenceError

    cause = getattr(error, "cause", None) or error
    if isinstance(cause, OSError) and cause.strerror:
        return f"{cause.strerror}: {cause.filename}" if cause.filename else cause.strerror
    if isinstance(cause, CaptureError | DeviceError | InferenceError):
        return str(cause)
    text = str(cause).strip().splitlines()
    # a Ray error's text is its traceback: its last line says what happened
    return f"{type(cause).__name__}: {text[-1] if text else ''}".rstrip(": ")


# ---- training ----------------------------------------------------------------------------


MIN_IMAGES_PER_WORKER = 16  # each worker's share of a batch: batch norm needs a few images


def training_workers(batch_size: int, cpus: float, wanted: int = 0) -> int:
    """DDP workers: `wanted`, else one per CPU of the cluster; each must get at least
    MIN_IMAGES_PER_WORKER images of a batch (batch norm is per worker)."""
    most = max(1, batch_size // MIN_IMAGES_PER_WORKER)
    if wanted > most:
        raise ClusterError(
            f"--workers {wanted}: a batch of {batch_size} gives each worker fewer than "
            f"{MIN_IMAGES_PER_WORKER} images (use at most {most}, or a larger --batch-size)"
        )
    return wanted or max(1, min(int(cpus), most))


def train(
    files: Sequence[str | os.PathLike],
    settings,
    workers: int,
    read: Callable[[list[str]], list],
    show_progress: bool = True,
):
    """inference.training.train over `workers` DDP processes (Ray Train's TorchTrainer,
    gloo): every worker reads the sessions from `files` with `read` (a module-level function:
    Ray sends it by name), the batches and the validation are split between them. Returns
    rank 0's TrainResult; a bar over epochs here."""
    import shutil
    import tempfile

    ray = _ray()
    try:
        from ray.train import RunConfig, ScalingConfig
        from ray.train.torch import TorchConfig, TorchTrainer
    except ImportError:
        raise ClusterError(INSTALL_HINT) from None

    sink = ray.remote(num_cpus=0)(_Sink).remote()
    # Ray Train's run state; nothing in it is kept (the result comes back by `sink`)
    storage = tempfile.mkdtemp(prefix="walkcap-ray-train-")
    trainer = TorchTrainer(
        _train_worker,
        train_loop_config={
            "files": [str(Path(f).resolve()) for f in files],
            "settings": settings,
            "sink": sink,
            "read": read,
        },
        torch_config=TorchConfig(backend="gloo"),
        scaling_config=ScalingConfig(
            num_workers=workers, use_gpu=False, resources_per_worker={"CPU": 1}
        ),
        run_config=RunConfig(
            name="walkcap-train",
            storage_path=storage,
        ),
    )
    outcome: dict = {}

    def fit() -> None:
        try:
            outcome["result"] = trainer.fit()
        except BaseException as e:  # reported below, in this thread
            outcome["error"] = e

    thread = threading.Thread(target=fit, name="walkcap-train-fit", daemon=True)
    thread.start()
    try:
        _follow(ray, sink, thread, settings.epochs, show_progress)
        thread.join()
    finally:  # interrupted, the cluster's end (connect) stops the workers
        shutil.rmtree(storage, ignore_errors=True)
    if "error" in outcome:
        raise ClusterError(f"training on the cluster failed: {describe(outcome['error'])}")
    result = ray.get(sink.result.remote())
    if result is None:
        raise ClusterError("training on the cluster ended without a result")
    if isinstance(result, BaseException):
        raise result
    return result


def _follow(ray, sink, thread: threading.Thread, epochs: int, show_progress: bool) -> None:
    """A bar over epochs from rank 0's figures, until the training thread ends."""
    from tqdm import tqdm

    with tqdm(total=epochs, desc="train (cluster)", unit="epoch", disable=not show_progress) as bar:
        while True:
            finished = not thread.is_alive()
            for entry in ray.get(sink.epochs.remote()):
                bar.update(1)
                bar.set_postfix(
                    loss=f"{entry['train_loss']:.3f}", val_acc=f"{entry['val_accuracy']:.3f}"
                )
            if finished:
                return
            time.sleep(0.5)


class _Sink:
    """Where rank 0 leaves each epoch's figures and the result, for the driver."""

    def __init__(self) -> None:
        self._epochs: list = []
        self._result = None

    def epoch(self, entry: dict) -> None:
        self._epochs.append(entry)

    def epochs(self) -> list:
        out, self._epochs = self._epochs, []
        return out

    def put(self, result) -> None:
        self._result = result

    def result(self):
        return self._result


def _train_worker(config: dict) -> None:
    """One DDP worker (Ray Train has set up the process group): the sessions read here,
    then inference.training.train, which splits the work by rank."""
    import ray
    import torch.distributed as dist

    from inference.errors import InferenceError
    from inference.training import train as train_sessions

    sink = config["sink"]
    rank = dist.get_rank()
    try:
        sessions = config["read"](config["files"])
        result = train_sessions(
            sessions,
            config["settings"],
            show_progress=False,
            on_epoch=(lambda entry: ray.get(sink.epoch.remote(entry))) if rank == 0 else None,
        )
    except (CaptureError, InferenceError) as e:  # the same on every rank: one says it
        if rank == 0:
            ray.get(sink.put.remote(e))
        return
    if rank == 0:
        ray.get(sink.put.remote(result))
