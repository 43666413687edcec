"""Batch fitting on Ray: many frames and sequences over a pool of actors.

Each worker is a Ray actor that loads the model once and keeps one :class:`panoman.Fitter`.
Independent frames go to the workers in chunks; a :class:`Sequence` goes to one worker whole
and is fitted in order by a :class:`panoman.Tracker`, so its warm starts are kept. A frame that
fails is reported with its error (:attr:`FrameResult.error`) and the others go on.

Example::

    from panoman.distributed import Sequence, fit_many
    out = fit_many("model.safetensors", [kp0, kp1, Sequence([kp2, kp3, kp4])])
    out[0].result.vertices          # frame 0, (V, 3)
    out[2][1].result.vertices       # the sequence's second frame

Needs ``ray`` (and ``tqdm`` for the progress bar): ``pip install "ray>=2.9" tqdm``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Iterable, List, Optional, Sequence as _Seq, Union

__all__ = ["Sequence", "FrameResult", "fit_many"]


class Sequence:
    """Frames of one sequence, fitted in order on one worker by a :class:`panoman.Tracker`
    (warm-started IK, temporal terms). Each frame is what :func:`fit_many` takes as a frame."""

    def __init__(self, frames: Iterable[Any]):
        self.frames = list(frames)

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"Sequence({len(self.frames)} frames)"


@dataclass
class FrameResult:
    """The outcome of one frame: ``result`` (a :class:`panoman.FitResult`) or ``error`` (the
    exception it raised, usually a :class:`panoman.Error`), never both."""

    result: Optional[Any] = None
    error: Optional[BaseException] = None

    @property
    def ok(self) -> bool:
        """Whether the frame was fitted."""
        return self.error is None


def _frame_kwargs(frame: Any) -> dict:
    """A frame as keyword arguments of ``Fitter.fit``: a dict with any of the keys
    ``keypoints``, ``weights``, ``points``, ``normals``, ``handles``; anything else (an array
    ``(133, 3)``, a ``{name: (x, y, z)}`` dict) is keypoints."""
    keys = {"keypoints", "weights", "points", "normals", "handles"}
    if isinstance(frame, dict) and frame and set(frame) <= keys:
        return dict(frame)
    return {"keypoints": frame}


class _Worker:
    """One actor: the model loaded once, one fitter for independent frames."""

    def __init__(self, model_path: str, options: dict, threads: Optional[int]):
        if threads:
            # The library's thread pool starts on first use: cap it before that.
            os.environ["RAYON_NUM_THREADS"] = str(threads)
        import panoman

        self._panoman = panoman
        self.model = panoman.Model.load(model_path)
        self.options = options
        self.fitter = panoman.Fitter(self.model)

    def fit_chunk(self, chunk):
        """Fits ``[(index, frame kwargs), ...]``; returns ``[(index, FrameResult), ...]``."""
        out = []
        for index, kwargs in chunk:
            try:
                out.append((index, FrameResult(result=self.fitter.fit(**kwargs, **self.options))))
            except Exception as e:  # reported per frame, the chunk goes on
                out.append((index, FrameResult(error=e)))
        return out

    def track(self, index, frames):
        """Fits one sequence in order; returns ``(index, [FrameResult, ...])``."""
        opts = dict(self.options)
        tracker = self._panoman.Tracker(self.model, opts.pop("method", "panoman"), **opts)
        results = []
        for kwargs in frames:
            try:
                results.append(FrameResult(result=tracker.track(**kwargs)))
            except Exception as e:
                results.append(FrameResult(error=e))
        return index, results


def fit_many(
    model_path: Union[str, os.PathLike],
    frames: _Seq[Any],
    *,
    method: str = "panoman",
    keypoint_sigma: float = 0.0,
    keypoint_weight: float = 10.0,
    workers: Optional[int] = None,
    chunk_size: int = 4,
    threads_per_worker: Optional[int] = 1,
    address: Optional[str] = None,
    num_cpus: Optional[int] = None,
    progress: bool = True,
) -> List[Union[FrameResult, List[FrameResult]]]:
    """Fits many frames and sequences on Ray; returns one entry per item of ``frames``, in
    order: a :class:`FrameResult` for a frame, a list of them for a :class:`Sequence`.

    - ``frames``: frames (see ``Fitter.fit``: a ``(133, 3)`` keypoint array in metres, a
      ``{name: (x, y, z)}`` dict, or a dict of ``keypoints``/``weights``/``points``/
      ``normals``/``handles``) and :class:`Sequence` s of them.
    - ``method``, ``keypoint_sigma`` (metres), ``keypoint_weight``: as in ``Fitter.fit``.
    - ``workers``: number of actors (default: the cluster's CPUs, at most one per task).
    - ``chunk_size``: independent frames per task.
    - ``threads_per_worker``: the library's threads in each actor (default 1: one actor per
      CPU); ``None`` keeps the library's default (all cores).
    - ``address``: an existing Ray cluster (``"auto"``, ``"ray://host:10001"``); default: the
      running Ray of this process, else a new local one (``ray.init(num_cpus=num_cpus)``),
      shut down on return.
    - ``progress``: a tqdm bar of fitted frames.
    """
    import ray

    model_path = os.fspath(model_path)
    if chunk_size < 1:
        raise ValueError("chunk_size must be ≥ 1")
    items = list(frames)
    started = False
    if not ray.is_initialized():
        if address is None:
            ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
        started = True
    try:
        return _run(ray, model_path, items, method, keypoint_sigma, keypoint_weight,
                    workers, chunk_size, threads_per_worker, progress)
    finally:
        if started:
            ray.shutdown()


def _run(ray, model_path, items, method, keypoint_sigma, keypoint_weight, workers,
         chunk_size, threads, progress):
    options = {"method": method, "keypoint_sigma": keypoint_sigma,
               "keypoint_weight": keypoint_weight}
    singles = [(i, _frame_kwargs(f)) for i, f in enumerate(items) if not isinstance(f, Sequence)]
    seqs = [(i, [_frame_kwargs(f) for f in s.frames]) for i, s in enumerate(items)
            if isinstance(s, Sequence)]
    chunks = [singles[k:k + chunk_size] for k in range(0, len(singles), chunk_size)]
    tasks = [("seq", s, len(s[1])) for s in seqs] + [("chunk", c, len(c)) for c in chunks]
    out: List[Any] = [None] * len(items)
    if not tasks:
        return out
    if workers is None:
        workers = max(1, int(ray.available_resources().get("CPU", 1)))
    workers = max(1, min(workers, len(tasks)))
    actor = ray.remote(num_cpus=1)(_Worker)
    pool = [actor.remote(model_path, options, threads) for _ in range(workers)]
    # Longest first onto the least loaded actor (a sequence stays whole on one actor; an
    # actor runs its tasks one after another, in submission order).
    load = [0] * workers
    pending = {}
    for kind, payload, size in sorted(tasks, key=lambda t: -t[2]):
        w = min(range(workers), key=lambda k: load[k])
        load[w] += size
        if kind == "seq":
            ref = pool[w].track.remote(*payload)
        else:
            ref = pool[w].fit_chunk.remote(payload)
        pending[ref] = (kind, payload, size)
    bar = _progress(sum(t[2] for t in tasks), progress)
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                kind, payload, size = pending.pop(ref)
                try:
                    value = ray.get(ref)
                except Exception as e:  # the actor died: every frame of the task failed
                    if kind == "seq":
                        out[payload[0]] = [FrameResult(error=e) for _ in payload[1]]
                    else:
                        for index, _ in payload:
                            out[index] = FrameResult(error=e)
                else:
                    if kind == "seq":
                        out[value[0]] = value[1]
                    else:
                        for index, r in value:
                            out[index] = r
                bar.update(size)
    finally:
        bar.close()
        for a in pool:
            ray.kill(a)
    return out


class _NoBar:
    def update(self, n):
        pass

    def close(self):
        pass


def _progress(total, enabled):
    if not enabled:
        return _NoBar()
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return _NoBar()
    return tqdm(total=total, unit="frame", desc="panoman fit")
