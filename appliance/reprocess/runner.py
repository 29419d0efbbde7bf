"""The driver of ``ogiflow reprocess``: plan, run segments as Ray tasks, merge, tabulate.

Ray Core tasks, one per segment (docs/design.md: ``ray.data.read_mcap`` puts a whole file in one
block, too coarse for triples): local Ray on all cores by default, or a running cluster
(``--address auto`` on a cluster node, ``ray://head:10001`` through Ray Client). A task
whose worker process or node dies is run again by Ray (``max_retries``); an exception in a
task is a failure of that segment only, reported at the end. Only this driver writes the
manifest, after a task has returned, so the manifest never claims more than exists.
"""

from __future__ import annotations

import os
import sys
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import appliance
from appliance.reprocess.jobs import Job
from appliance.reprocess.manifest import Manifest
from appliance.reprocess.tasks import merge_task, plan_task, segment_paths, segment_task

#: Ray re-runs a task whose worker or node died this many times.
MAX_RETRIES = 3


@dataclass
class RunSummary:
    """Counts of one run (printed at the end)."""

    inputs: int = 0
    jobs: int = 0
    segments: int = 0
    segments_done_before: int = 0
    segments_run: int = 0
    triples: int = 0
    failed_triples: int = 0
    failed_segments: list[str] = field(default_factory=list)
    bad_inputs: list[str] = field(default_factory=list)
    truncated_inputs: list[str] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)
    retries: int = 0
    wall_s: float = 0.0
    interrupted: bool = False

    def lines(self) -> list[str]:
        rate = self.triples / self.wall_s if self.wall_s > 0 else 0.0
        out = [f"reprocess: {self.inputs} input(s), {self.jobs} job(s), {self.segments} "
               f"segment(s) ({self.segments_done_before} done before, {self.segments_run} "
               f"run now, {len(self.failed_segments)} failed), {self.triples} triples "
               f"processed now ({self.failed_triples} failed), {self.retries} task "
               f"retries, {self.wall_s:.1f} s, {rate:.2f} triples/s"]
        out += [f"warning: {p} ends early (cut by a crash?): processed up to the cut"
                for p in self.truncated_inputs]
        out += [f"error: {e}" for e in self.bad_inputs + self.failed_segments]
        return out


def import_ray() -> Any:
    """``ray``, or a ValueError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ValueError("reprocess needs Ray: pip install 'ogiflow[cluster]' (or "
                         "tools/install.sh --cluster)") from None
    return ray


def _runtime_env() -> dict[str, Any]:
    """Workers import the same ogiflow as this driver when it runs from a source tree."""
    root = Path(appliance.__file__).resolve().parent.parent
    if "site-packages" in root.parts or "dist-packages" in root.parts:
        return {}
    return {"env_vars": {"PYTHONPATH": str(root)}}


class Runner:
    """One ``ogiflow reprocess`` run over ``jobs``, results in ``out_dir``."""

    def __init__(self, jobs: Sequence[Job], out_dir: Path, *, address: str | None,
                 num_cpus: int | None = None, progress: Any = None) -> None:
        self.jobs = list(jobs)
        self.out_dir = out_dir
        self.address = address
        self.num_cpus = num_cpus
        self.progress = progress
        self.manifest = Manifest(out_dir)
        self.run_id = uuid.uuid4().hex[:12]
        self.summary = RunSummary(inputs=len({j.input for j in jobs}), jobs=len(jobs))
        self._started_ray = False
        self._outputs: set[Path] = set()

    # ------------------------------------------------------------------ ray

    def _init(self) -> Any:
        if self.address is None and "ray" not in sys.modules:
            # A local Ray stays on loopback: Ray resolves 127.0.0.1 to the host's network
            # address (and listens there) unless clusters are "disabled", which is read from
            # the environment when ray is first imported. A cluster has its own addresses.
            os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        ray = import_ray()
        if not ray.is_initialized():
            # A local Ray stays on loopback; a cluster has its own addresses.
            local = {"_node_ip_address": "127.0.0.1"} if self.address is None else {}
            ray.init(address=self.address, num_cpus=self.num_cpus, runtime_env=_runtime_env(),
                     **local,
                     include_dashboard=False, log_to_driver=False,
                     logging_level="WARNING", configure_logging=True)
            self._started_ray = True
        return ray

    def run(self) -> RunSummary:
        """Do every missing piece; Ctrl-C keeps what finished (``summary.interrupted``)."""
        t0 = time.monotonic()
        ray = self._init()
        pending: dict[Any, tuple[str, Job, Any]] = {}
        try:
            self._run(ray, pending)
        except KeyboardInterrupt:
            # No ray.cancel: the tasks of this driver end with it (ray.shutdown below, or
            # the job's end on a cluster); cancelling while results arrive crashes Ray 2.60.
            self.summary.interrupted = True
        finally:
            self.summary.wall_s = time.monotonic() - t0
            self.summary.retries = self._retries()
            if self._started_ray:
                ray.shutdown()
        return self.summary

    def _run(self, ray: Any, pending: dict[Any, tuple[str, Job, Any]]) -> None:
        plan_r = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)(plan_task)
        seg_r = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)(segment_task)
        merge_r = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)(merge_task)
        plans: dict[str, dict[str, Any]] = {}
        for job in self.jobs:
            if job.key in self.manifest.plans:
                plans[job.key] = self.manifest.plans[job.key]
            else:
                pending[plan_r.remote(job)] = ("plan", job, None)
        total = done = 0

        def submit(job: Job) -> None:
            nonlocal total
            plan = plans[job.key]
            if "error" in plan:
                self.summary.bad_inputs.append(plan["error"])
                return
            if plan.get("truncated"):
                self.summary.truncated_inputs.append(str(job.input))
            segs = plan["segments"]
            self.summary.segments += len(segs)
            missing = [i for i in range(len(segs))
                       if not self.manifest.segment_done(job.key, i)]
            self.summary.segments_done_before += len(segs) - len(missing)
            for i in missing:
                first, stop = segs[i]
                total += max(0, min(stop, plan["pairs"] - 2) - first)
                ref = seg_r.remote(job, i, first, stop, plan["pairs"],
                                   self.manifest.segment_dir(job.key), self.run_id)
                pending[ref] = ("segment", job, i)
            if not missing:
                self._merge_if_ready(job, plans, pending, merge_r)

        for job in self.jobs:
            if job.key in plans:
                submit(job)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            if self.progress is not None and total:
                self.progress(done, total)
            if not ready:
                continue
            ref = ready[0]
            kind, job, index = pending.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayError as exc:
                text = str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc)
                self.summary.failed_segments.append(f"{job.input} {kind} {index}: {text}")
                continue
            if kind == "plan":
                entry = {"kind": "plan", "job": job.key, "input": str(job.input), **result}
                if "error" not in result:
                    self.manifest.append(entry)
                plans[job.key] = entry
                submit(job)
            elif kind == "segment":
                self.manifest.append({"kind": "segment", "job": job.key, "run": self.run_id,
                                      **result})
                self.summary.segments_run += 1
                self.summary.triples += result["triples"]
                self.summary.failed_triples += result["failed"]
                done += result["expected"]
                self._merge_if_ready(job, plans, pending, merge_r)
            else:
                self.manifest.append({"kind": "merged", "job": job.key, **result})
                self.summary.outputs.append(result["output"])
        if self.progress is not None and total:
            self.progress(done, total)

    def _merge_if_ready(self, job: Job, plans: dict[str, dict[str, Any]],
                        pending: dict[Any, tuple[str, Job, Any]], merge_r: Any) -> None:
        plan = plans[job.key]
        n = len(plan["segments"])
        if self.manifest.merged_done(job.key):
            self.summary.outputs.append(self.manifest.merged[job.key]["output"])
            return
        if all(self.manifest.segment_done(job.key, i) for i in range(n)):
            out = job.output(self.out_dir, plan["appliance_id"])
            taken = {Path(e["output"]) for k, e in self.manifest.merged.items() if k != job.key}
            if out in taken or out in self._outputs:  # same name from another folder
                out = out.with_name(f"{out.stem}-{job.key[:8]}.mcap")
            self._outputs.add(out)
            ref = merge_r.remote(job, n, self.manifest.segment_dir(job.key), out)
            pending[ref] = ("merge", job, None)

    def _retries(self) -> int:
        """Attempts of this run beyond the first, per segment (from the attempts logs)."""
        retries = 0
        for d in {self.manifest.segment_dir(j.key) for j in self.jobs}:
            for log in d.glob("seg-*.attempts") if d.is_dir() else []:
                runs = [line.split()[0] for line in log.read_text().splitlines() if line]
                retries += max(0, runs.count(self.run_id) - 1)
        return retries

    # ------------------------------------------------------------------ table

    def write_table(self, swept: Sequence[str]) -> Path | None:
        """One Parquet table of every finished job's summaries (``OUT/summaries.parquet``)."""
        # pyarrow only for the tables of export and reprocess (not the daemon).
        import pyarrow as pa
        import pyarrow.parquet as pq

        tables = []
        for job in self.jobs:
            plan = self.manifest.plans.get(job.key)
            if plan is None or not self.manifest.merged_done(job.key):
                continue
            for i in range(len(plan["segments"])):
                t = pq.read_table(segment_paths(self.manifest.segment_dir(job.key), i)[1])
                n = t.num_rows
                front = {"appliance_id": pa.array([plan["appliance_id"]] * n, pa.string()),
                         "input": pa.array([str(job.input)] * n, pa.string()),
                         "parameters": pa.array([job.label] * n, pa.string())}
                for k in swept:
                    front[k] = pa.array([job.overrides[k]] * n)
                for name, col in reversed(front.items()):
                    t = t.add_column(0, name, col)
                tables.append(t)
        if not tables:
            return None
        path = self.out_dir / "summaries.parquet"
        part = path.with_name(f".{path.name}.part")
        pq.write_table(pa.concat_tables(tables, promote_options="default"), part,
                       compression="zstd")
        part.replace(path)
        return path


def print_summary(summary: RunSummary, table: Path | None) -> None:
    for line in summary.lines():
        print(line, file=sys.stderr if line.startswith(("warning", "error")) else sys.stdout)
    for out in summary.outputs:
        print(f"  {out}")
    if table is not None:
        print(f"  {table}")
