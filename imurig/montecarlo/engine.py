"""The Monte-Carlo engine: N seeded runs of a campaign on dask.distributed, streamed to disk.

    study config (campaign, params, master seed, distributions)  -> study.json
    run i: the registry stream "montecarlo/run" of (master, i)  (imurig.kernel.random_streams)
      -> campaign.run(params, seed, distributions, estimator)   on a Dask worker
      -> runs/run_<i>.json written atomically as soon as the run returns
    all runs -> statistics -> report(study, campaign), when given: results.h5, summary.json,
                report.md, figures (imurig.reports.montecarlo.write_study_outputs, as the CLI does)

Nothing is lost: each finished run is on disk before the next result is taken; ``resume``
skips the runs already on disk and refuses a study whose settings differ; a run whose task
raises is retried (``retries``), and a run on a worker that dies is rescheduled by the
scheduler (``distributed.scheduler.allowed-failures``, 3 by default).

Python API (used by the CLI and by the bring-your-own-estimator scorer)::

    from imurig.montecarlo import run_study
    from imurig.reports.montecarlo import write_study_outputs
    study = run_study("tilt-table", runs=200, master_seed=1, out="mc", estimator=my_fn,
                      report=write_study_outputs)
    study.rows        # {run index: [parameter rows]}
    study.stats       # per-parameter bias, RMS, CRLB, coverage
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import resource
import shutil
import socket
import tempfile
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imurig.kernel import random_streams
from imurig.kernel.errors import ConfigError, ImurigError, OutputExistsError
from imurig.kernel.progress import progress
from imurig.montecarlo import distributions as _dist
from imurig.montecarlo import registry
from imurig.montecarlo.stats import parameter_stats

FORMAT = 2   # 2: run seeds from the stream registry (format 1 used SeedSequence(master, spawn_key=(i,)))
RUN_FILE = "run_{:06d}.json"
SCHEDULER_TIMEOUT_S = 5.0


class StudyInterrupted(ImurigError):
    """The study stopped before all runs finished (its finished runs are on disk; resume it)."""


# ------------------------------------------------------------------ one run
def run_seed(master_seed: int, index: int) -> np.random.SeedSequence:
    """The SeedSequence of run ``index``: the registry stream ``montecarlo/run`` of the master seed
    and run index (:mod:`imurig.kernel.random_streams`)."""
    return random_streams.seed_sequence("montecarlo/run", int(master_seed), run=int(index))


def execute_run(campaign, params: dict, distributions: dict, master_seed: int, index: int, estimator=None) -> dict:
    """Run ``index`` of a study (what a Dask worker executes). Returns a JSON-ready dict."""
    t0 = time.perf_counter()
    ss = run_seed(master_seed, index)
    out = campaign.run(params, ss, distributions, estimator)
    out["info"]["wall_s"] = time.perf_counter() - t0
    out["info"]["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    out["info"]["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # of the worker, so far
    return {"index": int(index), "seed": {"entropy": int(master_seed), "spawn_key": [int(k) for k in ss.spawn_key]},
            **out}


def reproduce_run(campaign, index: int, master_seed: int, params: dict | None = None, distributions=None,
                  estimator=None) -> dict:
    """Run ``index`` alone, in this process (no Dask): equals its row in the study."""
    camp = registry.get(campaign) if isinstance(campaign, str) else campaign
    p = camp.validate(params)
    dist = _dist.normalise(distributions, camp.sources())
    return execute_run(camp, p, dist, master_seed, index, estimator)


# ------------------------------------------------------------------ study
@dataclass
class Study:
    """A finished (or loaded) study: config, run rows by index, statistics."""

    config: dict
    runs: dict = field(default_factory=dict)       # index -> run dict (rows, info, seed)
    path: Path | None = None
    timing: dict = field(default_factory=dict)

    @property
    def rows(self) -> dict[int, list[dict]]:
        return {i: r["rows"] for i, r in sorted(self.runs.items())}

    @property
    def stats(self) -> list[dict]:
        return parameter_stats(self.rows)


def _config(campaign_name: str, params: dict, master_seed: int, dist: dict, estimator) -> dict:
    est = None
    if estimator is not None:
        est = getattr(estimator, "__qualname__", None) or type(estimator).__qualname__
        est = f"{getattr(estimator, '__module__', '?')}.{est}"
    return {"format": FORMAT, "campaign": campaign_name, "params": params, "master_seed": int(master_seed),
            "distributions": dist, "estimator": est}


def _fingerprint(cfg: dict) -> str:
    return hashlib.sha256(json.dumps(cfg, sort_keys=True).encode()).hexdigest()[:12]


def _atomic_json(path: Path, obj) -> None:
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(obj, f, allow_nan=True)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _prepare_out(out: Path, cfg: dict, runs: int, overwrite: bool, resume: bool) -> set[int]:
    """Create or reopen a study folder; returns the run indices already on disk."""
    study_file = out / "study.json"
    if out.exists() and any(out.iterdir()):
        if resume:
            if not study_file.exists():
                raise ConfigError(f"cannot resume: {out} holds no study.json (not a Monte-Carlo study folder)")
            old = json.loads(study_file.read_text())
            diff = sorted(k for k in set(cfg) | set(old.get("config", {})) if cfg.get(k) != old["config"].get(k))
            if diff:
                detail = "; ".join(f"{k}: stored {old['config'].get(k)!r}, now {cfg.get(k)!r}" for k in diff)
                raise ConfigError(f"cannot resume {out}: the study was started with different settings ({detail}). "
                                  "Resume with the same settings, or start a new study (another --out, or "
                                  "--overwrite)")
        elif overwrite:
            if not study_file.exists():
                raise OutputExistsError(f"{out} exists and is not a Monte-Carlo study folder; refusing to delete it "
                                        "even with --overwrite; choose another --out")
            shutil.rmtree(out)
        else:
            raise OutputExistsError(f"{out} exists; pass --resume to continue that study, --overwrite to replace "
                                    "it, or choose another --out")
    (out / "runs").mkdir(parents=True, exist_ok=True)
    _atomic_json(study_file, {"config": cfg, "runs": int(runs)})
    return _runs_on_disk(out)


def _runs_on_disk(out: Path) -> set[int]:
    done = set()
    for f in (out / "runs").glob("run_*.json"):
        try:
            done.add(int(f.stem.split("_")[1]))
        except ValueError:
            continue
    return done


@contextlib.contextmanager
def dask_client(client=None, scheduler: str | None = None, workers: int | None = None,
                memory_limit: str = "4GiB", processes: bool = True):
    """A dask.distributed Client: the one given, one connected to ``scheduler`` (address), or a
    LocalCluster of ``workers`` single-threaded worker processes on this machine."""
    if client is not None:
        yield client
        return
    from distributed import Client, LocalCluster  # dask: heavy, loaded when a cluster is needed

    if scheduler:
        try:
            c = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
        except (OSError, TimeoutError, ValueError) as e:
            raise ConfigError(f"cannot reach the Dask scheduler at {scheduler!r} within {SCHEDULER_TIMEOUT_S:g} s "
                              f"({type(e).__name__}: {e}). Start one (`dask scheduler` and `dask worker ADDRESS`) or "
                              "omit --scheduler to use a local cluster") from None
        try:
            yield c
        finally:
            c.close()
        return
    n = workers or min(2, os.cpu_count() or 1)
    if n < 1:
        raise ConfigError(f"--workers must be >= 1, got {n}")
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=processes, memory_limit=memory_limit,
                           dashboard_address=":0", silence_logs=logging.ERROR)
    c = Client(cluster)
    try:
        yield c
    finally:
        c.close()
        cluster.close()


def run_study(campaign, runs: int, master_seed: int = 0, params: dict | None = None, distributions: dict | None = None,
              estimator=None, client=None, scheduler: str | None = None, workers: int | None = None,
              out=None, overwrite: bool = False, resume: bool = False, retries: int = 2,
              processes: bool = True, stop_after: int | None = None, report=None,
              desc: str | None = None) -> Study:
    """Run (or resume) a Monte-Carlo study; see the module doc.

    campaign : registered name ("tilt-table") or a campaign object (registry contract).
    runs : number of runs N >= 1. master_seed : the study's one seed.
    params : campaign settings (schedule etc.), completed with the campaign's defaults.
    distributions : {source: {mean, std|variance}} user-set error distributions.
    estimator : optional ``f(recording) -> [{name, estimate, std_error}]`` replacing the
        campaign's calibration (runs on the workers; must be picklable).
    client / scheduler / workers : an existing dask Client, a scheduler address, or the size
        of the local cluster (default: 2 worker processes, one thread each).
    out : study folder (study.json and the streamed run files). Without ``out`` the runs are
        kept in memory only.
    report : optional ``report(study, campaign)``, called with ``out`` complete, writing the
        study's outputs into it (e.g. :func:`imurig.reports.montecarlo.write_study_outputs`:
        results.h5, summary.json, report.md, figures, study.rrd).
    stop_after : stop after this many new runs (test hook for interrupted studies).
    """
    camp = registry.get(campaign) if isinstance(campaign, str) else campaign
    if not isinstance(runs, (int, np.integer)) or isinstance(runs, bool) or runs < 1:
        raise ConfigError(f"the number of runs must be a whole number >= 1, got {runs!r}")
    if not isinstance(master_seed, (int, np.integer)) or master_seed < 0:
        raise ConfigError(f"the master seed must be a whole number >= 0, got {master_seed!r}")
    p = camp.validate(params)
    dist = _dist.normalise(distributions, camp.sources())
    cfg = _config(camp.name, p, master_seed, dist, estimator)
    out = Path(out) if out is not None else None
    peek = _runs_on_disk(out) if (out is not None and resume) else set()
    need_client = any(i not in peek for i in range(runs))
    study = Study(config=cfg, path=out)
    t0 = time.perf_counter()
    sub = None
    # connect first: an unreachable scheduler must fail before anything is written
    with (dask_client(client, scheduler, workers, processes=processes) if need_client
          else contextlib.nullcontext(None)) as c:
        done = _prepare_out(out, cfg, runs, overwrite, resume) if out is not None else set()
        todo = [i for i in range(runs) if i not in done]
        if todo:
            bar = {"total": runs, "desc": desc or f"Monte-Carlo {camp.name}", "unit": "run",
                   "initial": len(done & set(range(runs)))}
            sub = _collect(c, study, camp, p, dist, master_seed, todo, estimator, retries, stop_after, bar)
    wall = time.perf_counter() - t0
    if out is not None:
        for i in range(runs):
            if i not in study.runs:
                study.runs[i] = json.loads((out / "runs" / RUN_FILE.format(i)).read_text())
    new = sub["new"] if sub else 0
    compute = (sub["t_end"] - sub["t_sub"]) if new else None
    study.timing = {"wall_s": wall, "compute_s": compute, "new_runs": new,
                    "runs_per_min": 60 * new / compute if compute else None,
                    "runs_per_min_incl_startup": 60 * new / wall if new and wall > 0 else None,
                    "workers": _n_workers(client, scheduler, workers)}
    if out is not None and report:
        report(study, camp)
    return study


def _collect(c, study: Study, camp, p: dict, dist: dict, master_seed: int, todo: list[int], estimator, retries: int,
             stop_after: int | None, bar: dict) -> dict:
    """Submit runs ``todo`` to the client ``c`` and take each result as it comes: on disk
    (``study.path``) before the next is taken; ``bar``: the progress bar's settings. Returns
    the count and the submit/last-result times."""
    from distributed import as_completed  # dask: heavy, loaded when a cluster is needed

    out = study.path
    # unique per session: a cancelled future of an interrupted session must not share a key
    key = f"{_fingerprint(study.config)}-{uuid.uuid4().hex[:8]}"
    t_sub = time.perf_counter()
    futures = [c.submit(execute_run, camp, p, dist, master_seed, i, estimator, key=f"imurig-mc-{key}-{i}",
                        retries=retries, pure=False) for i in todo]
    new, t_end = 0, None
    try:
        with progress(**bar) as shown:
            for fut in as_completed(futures):
                res = fut.result()
                if out is not None:
                    _atomic_json(out / "runs" / RUN_FILE.format(res["index"]), res)
                study.runs[res["index"]] = res
                new += 1
                shown.update(1)
                t_end = time.perf_counter()
                if stop_after is not None and new >= stop_after:
                    raise StudyInterrupted(f"stopped after {new} new runs (stop_after); {out} holds them: "
                                           "resume with --resume")
    finally:
        for f in futures:
            if not f.done():
                f.cancel()
    return {"new": new, "t_sub": t_sub, "t_end": t_end}


def _n_workers(client, scheduler, workers):
    if client is not None:
        with contextlib.suppress(Exception):
            return len(client.scheduler_info()["workers"])
        return None
    if scheduler:
        return None
    return workers or min(2, os.cpu_count() or 1)


def load_study(out) -> Study:
    """Read a study folder (config and every run file on disk)."""
    out = Path(out)
    f = out / "study.json"
    if not f.exists():
        raise ConfigError(f"{out} holds no study.json: not a Monte-Carlo study folder")
    meta = json.loads(f.read_text())
    st = Study(config=meta["config"], path=out)
    for g in sorted((out / "runs").glob("run_*.json")):
        r = json.loads(g.read_text())
        st.runs[r["index"]] = r
    return st
