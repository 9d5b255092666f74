"""Running a grid: its cases dealt into tasks, run in this process, on local processes or on a
Dask cluster, every case stored under a hash of its inputs.

Tasks: the cases are dealt round robin into tasks, so that neighbouring (similar) cases
spread over the workers. The cases of a task are solved together (`vibrissa.grid_study.
run_cases`, the same bits as each alone), and batched Newton steps cost less per case the more
cases share them (the paper's 25 sweeps: 0.38 s a case alone, 0.19 s in sixes, 0.16 s in
twelves and more), hence few large tasks: one per worker where the cases allow, at most
`MAX_TASK_CASES` each, so that a long grid stores its cases (and shows its progress) as it
goes. A scene is a task of its own (its whiskers are batched within it). The function a
worker runs is plain Python (`run_cases`), never a compiled kernel (distributed#4597: jitted
functions do not pickle to a worker reliably).

numba's cache: before fanning out, this process runs a short sweep and its Step 2 (`warm_up`),
so every kernel is compiled and cached once; the workers then load it instead of compiling the
same kernels at once, whose parallel first writes of a ``cache=True`` entry can corrupt it
(numba#4807). The cache is node-local: each machine of a cluster warms its own (``make setup``
or a `warm_up` run there).

Store: ``<out>/cases/<key>.parquet`` per case, ``key`` the SHA-256 of the case's inputs and the
package version (`case_key`), written whole as each task returns. A run skips the cases whose
file is there, so an interrupted grid resumes where it stopped and a grid with one parameter
changed computes only the cases it touches; the tables are then assembled from the store in
grid order, so they do not depend on how the cases were run.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vibrissa.formats.files import whole_file
from vibrissa.frames import Transform
from vibrissa.grid_study import (
    GridCase,
    SceneCase,
    SceneStudy,
    case_columns,
    case_summary,
    run_cases,
    scene_columns,
    scene_summary,
)
from vibrissa.scene import Scene, SceneObject, Whisker, robot_path, worker_pool
from vibrissa.studies.grid_file import Grid
from vibrissa.study import PAPER_SURFACE, StudyCase

PACKAGE_VERSION = importlib.metadata.version("vibrissa")
MAX_TASK_CASES = 32
"""Trail cases of one task at most (batching gains little beyond a dozen)."""
PARAMETER_COLUMNS = ("surface_m", "y0_m", "mu", "step", "length_m", "ei_nm2", "taper_ratio",
                     "precurvature_1pm", "poisson_ratio")
"""A trail case's inputs, the first columns of every table after ``case`` (its index in the
grid) and ``key`` (its file in the store)."""
SCENE_PARAMETER_COLUMNS = ("scene", "mu", "length_m", "ei_nm2")
"""A scene case's inputs, in the same place (``length_m``, ``ei_nm2`` NaN: the scene's rods)."""

LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}
"""Dask settings of the LocalCluster of ``--scheduler local``: no statistical profiler, slower
event-loop ticks and monitors (a CPU-bound task keeps the GIL longer)."""

Case = GridCase | SceneCase
Result = StudyCase | SceneStudy

_SUMMARY_METADATA = b"vibrissa.case_summary"
_TEXT_COLUMNS = ("surface_m", "phase", "state", "scene", "whisker", "object")


def _column_type(name: str) -> pa.DataType:
    """Every column's type, fixed (a case without equilibria has the same schema)."""
    if name in _TEXT_COLUMNS:
        return pa.string()
    return {"refined": pa.bool_(), "status": pa.int64()}.get(name, pa.float64())

ProgressCallback = Callable[[int, int, int], None]
"""``progress(cases_done, cases_total, equilibria_done)``."""


def case_key(case: Case) -> str:
    """SHA-256 (hex) of the case's inputs (`GridCase.inputs`: the surface spec in its
    canonical form; `SceneCase.inputs`: the scene's content) and the package version: the
    case's name in the store."""
    text = json.dumps({**case.inputs(), "vibrissa": PACKAGE_VERSION}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def warm_up(scenes: bool = False) -> None:
    """Compile (or load) numba's kernels of Step 1 and Step 2 in this process, once: two short
    sweeps past the paper's object, one with tip and stick phases, one tangential; with
    ``scenes`` also a short scene (`WARM_UP_SCENE`: a robot path, Step 2 through the poses)."""
    for kind, cases in (("trails", [GridCase(PAPER_SURFACE, y0, 0.4, 0.02) for y0 in (0.0, 0.4)]),
                        ("scenes", [SceneCase("warm-up", WARM_UP_SCENE, 0.4)] if scenes else [])):
        if cases and kind not in _WARM:
            run_cases(cases)
            _WARM.add(kind)


_WARM: set[str] = set()
"""The kinds of case whose kernels this process has loaded (`warm_up`)."""


WARM_UP_SCENE = Scene(
    0.4, (SceneObject("ball", "sphere", {"radius_m": 0.01}, Transform(translation=(0.0, 0.0, 0.035))),),
    (Whisker("w", 0.05, 1e-4),),
    robot_path(np.linspace(0.0, 1.0, 40), np.linspace([0.03, 0.0, 0.0], [-0.06, 0.0, 0.0], 40),
               np.tile([0.0, 0.0, 0.0, 1.0], (40, 1))))
"""A 50 mm rod driven 90 mm along -x past a 10 mm ball: tip contact, then tangential, snap-off."""


def deal(n_cases: int, n_workers: int, per_task: int = MAX_TASK_CASES) -> list[list[int]]:
    """Case indices dealt round robin into tasks: as few as keep each at most ``per_task``
    cases, as many for each worker, and at least two (a stopped grid has stored some), fewer
    when there are fewer cases."""
    n_tasks = max(2, n_workers, math.ceil(n_cases / per_task))
    n_tasks = min(n_cases, math.ceil(n_tasks / n_workers) * n_workers)
    return [list(range(t, n_cases, n_tasks)) for t in range(n_tasks)]


def _per_task(cases: Sequence[Case]) -> int:
    """Cases of a task at most: `MAX_TASK_CASES` trails, or one scene."""
    return 1 if isinstance(cases[0], SceneCase) else MAX_TASK_CASES


def compute(cases: Sequence[Case], workers: int | None = None, scheduler: str | None = None
            ) -> Iterator[tuple[list[int], list[Result]]]:
    """Step 1 and Step 2 of ``cases``: ``(indices, results)`` per task as tasks finish.

    ``workers``: local processes (default: all cores; 1: in this process), or the workers of
    the LocalCluster that ``scheduler="local"`` starts; ``scheduler``: ``"local"`` or the
    address of a Dask distributed scheduler (its workers decide how many run).
    """
    n_workers = _workers(workers)
    if not cases:
        return
    if scheduler is not None:
        yield from _on_dask(_task, lambda indices: (indices, [cases[i] for i in indices]), cases,
                            n_workers, scheduler)
        return
    tasks = [(indices, [cases[i] for i in indices])
             for indices in deal(len(cases), n_workers, _per_task(cases))]
    yield from _on_local_workers(_task, tasks, n_workers, isinstance(cases[0], SceneCase))


def _workers(workers: int | None) -> int:
    n_workers = (os.cpu_count() or 1) if workers is None else workers
    if n_workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return n_workers


T = TypeVar("T")
R = TypeVar("R")


def _on_local_workers(function: Callable[[T], R], tasks: Sequence[T], n_workers: int,
                      scenes: bool) -> Iterator[R]:
    """``function`` of each task as tasks finish: in this process (one worker), or on
    ``n_workers`` processes forked after `warm_up` (they inherit the loaded kernels)."""
    if n_workers == 1:
        yield from map(function, tasks)
        return
    warm_up(scenes)
    context = multiprocessing.get_context("fork")
    # Pool's exit terminates the workers: Ctrl-C or an error ends the run at once
    with worker_pool(min(n_workers, len(tasks)), context) as pool:
        yield from pool.imap_unordered(function, tasks)


def _task(task: tuple[list[int], list[Case]]) -> tuple[list[int], list[Result]]:
    """One task of a local worker: its case indices and `run_cases` of its cases."""
    indices, cases = task
    return indices, run_cases(cases)


def _stored_task(task: tuple[CaseStore, list[int], list[str], list[Case]]) -> tuple[list[int], int]:
    """One task of a local worker that stores its cases itself (the store is on this machine):
    its case indices and their equilibria."""
    store, indices, keys, cases = task
    return indices, _write(store, keys, cases, run_cases(cases))


def _equilibria(result: Result) -> int:
    """A case's equilibria: a sweep's steps, or a scene's rows (whiskers x samples)."""
    return sum(len(r.t) for r in result.results) if isinstance(result, SceneStudy) else result.sweep.n_steps


def _on_dask(function: Callable[[T], R], task_of: Callable[[list[int]], T], cases: Sequence[Case],
             n_workers: int, scheduler: str) -> Iterator[R]:
    """``function`` of each task (``task_of`` its case indices) as tasks finish, on the
    LocalCluster of ``n_workers`` processes that ``scheduler="local"`` starts, or on the Dask
    scheduler at the address ``scheduler``; its tasks dealt for the workers' threads."""
    from dask.distributed import Client, LocalCluster, as_completed

    warm_up(isinstance(cases[0], SceneCase))
    if scheduler == "local":
        import dask

        # A worker's event loop wakes to sample every thread's stack (10 ms), to watch itself
        # (20 ms) and its memory (100 ms), each time taking the GIL from the task's thread: the
        # large grid of bench_study_grid.py computed 8 % slower per task with the profiler, 14 %
        # with all three. A cluster of one's own turns them off or down (docs/STUDIES.md).
        with dask.config.set(LOCAL_CLUSTER_CONFIG):
            cluster: LocalCluster | None = LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        cluster, client = None, Client(scheduler)
    try:
        slots = sum(client.nthreads().values()) or n_workers
        futures = [client.submit(function, task_of(indices), pure=False)
                   for indices in deal(len(cases), slots, _per_task(cases))]
        for future in as_completed(futures):
            yield future.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


class CaseStore:
    """One Parquet file per case, ``<folder>/<key>.parquet``: its equilibria (the parameter
    columns, then `vibrissa.grid_study.EQUILIBRIUM_COLUMNS` or, for a scene,
    `vibrissa.grid_study.SCENE_EQUILIBRIUM_COLUMNS`) and its summary as JSON in the file's
    metadata. A file is written whole, so one that is there is complete."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.parquet"

    def has(self, key: str) -> bool:
        return self.path(key).is_file()

    def write(self, key: str, case: Case, result: Result) -> None:
        if isinstance(case, SceneCase):
            assert isinstance(result, SceneStudy)
            columns, summary_of = scene_columns(case, result), scene_summary(case, result)
        else:
            assert isinstance(result, StudyCase)
            columns, summary_of = case_columns(result), case_summary(case, result)
        n = len(next(iter(columns.values())))
        values = {**{name: [value] * n for name, value in case.parameters().items()}, **columns}
        table = pa.table({name: pa.array(column, _column_type(name))
                          for name, column in values.items()})
        summary = json.dumps({**case.parameters(), **summary_of})
        table = table.replace_schema_metadata({_SUMMARY_METADATA: summary.encode()})
        with whole_file(self.path(key)) as partial:
            pq.write_table(table, partial)

    def read(self, key: str) -> tuple[pa.Table, dict[str, Any]]:
        """The case's equilibria (without the file's metadata) and its summary."""
        table = pq.read_table(self.path(key))
        summary = json.loads(table.schema.metadata[_SUMMARY_METADATA])
        return table.replace_schema_metadata(None), summary


@dataclass(frozen=True)
class GridRun:
    """The tables of a grid and how they were made.

    Attributes
    ----------
    equilibria : pyarrow.Table
        Every equilibrium of every case, in grid order: ``case``, ``key``, the parameter
        columns, then `vibrissa.grid_study.EQUILIBRIUM_COLUMNS` (a scene's:
        `vibrissa.grid_study.SCENE_EQUILIBRIUM_COLUMNS`, a row per whisker and path sample).
    summary : pyarrow.Table
        One row per case: ``case``, ``key``, the parameters and `case_summary`'s keys.
    computed, reused : int
        Cases computed by this run and cases found in the store.
    computed_equilibria : int
        Equilibria of the cases computed by this run.
    elapsed_s : float
        Wall time of the run, s.
    """

    equilibria: pa.Table
    summary: pa.Table
    computed: int
    reused: int
    computed_equilibria: int
    elapsed_s: float


def run_grid(grid: Grid, store: CaseStore, workers: int | None = None,
             scheduler: str | None = None, progress: ProgressCallback | None = None) -> GridRun:
    """Compute the cases of ``grid`` missing from ``store``, store each task's cases as it
    finishes (local workers write them themselves; with a ``scheduler`` this process does, as
    the tasks come back from `compute`), and assemble the tables from the store."""
    start = time.perf_counter()
    keys = [case_key(case) for case in grid.cases]
    missing = sorted({key: i for i, key in enumerate(keys) if not store.has(key)}.values())
    done = len(grid.cases) - len(missing)
    equilibria = 0
    if progress:
        progress(done, len(grid.cases), equilibria)
    if missing:
        todo = [grid.cases[i] for i in missing]
        todo_keys = [keys[i] for i in missing]
        n_workers = _workers(workers)
        finished: Iterator[tuple[list[int], int]]
        scenes = isinstance(todo[0], SceneCase)

        def task_of(indices: list[int]) -> tuple[CaseStore, list[int], list[str], list[Case]]:
            return store, indices, [todo_keys[i] for i in indices], [todo[i] for i in indices]

        if scheduler is None:  # workers on this machine store their cases themselves
            tasks = [task_of(indices) for indices in deal(len(todo), n_workers, _per_task(todo))]
            finished = _on_local_workers(_stored_task, tasks, n_workers, scenes)
        elif scheduler == "local":
            finished = _on_dask(_stored_task, task_of, todo, n_workers, scheduler)
        else:  # a cluster's workers may not reach the store: this process writes
            finished = ((indices, _write(store, [todo_keys[i] for i in indices],
                                         [todo[i] for i in indices], results))
                        for indices, results in compute(todo, n_workers, scheduler))
        for indices, computed in finished:
            equilibria += computed
            done += len(indices)
            if progress:
                progress(done, len(grid.cases), equilibria)
    tables, rows = [], []
    for index, key in enumerate(keys):
        table, summary = store.read(key)
        head = {"case": pa.array([index] * table.num_rows, pa.int64()),
                "key": pa.array([key] * table.num_rows, pa.string())}
        for position, (name, column) in enumerate(head.items()):
            table = table.add_column(position, name, column)
        tables.append(table)
        rows.append({"case": index, "key": key, **summary})
    return GridRun(pa.concat_tables(tables), pa.Table.from_pylist(rows), len(missing),
                   len(grid.cases) - len(missing), equilibria, time.perf_counter() - start)


def _write(store: CaseStore, keys: Sequence[str], cases: Sequence[Case], results: Sequence[Result]) -> int:
    """Store the results of a task computed elsewhere; their equilibria."""
    for key, case, result in zip(keys, cases, results, strict=True):
        store.write(key, case, result)
    return sum(_equilibria(result) for result in results)


def same_bits(a: pa.Table, b: pa.Table) -> bool:
    """Whether two tables are the same bit for bit: schemas, and every value's bytes (NaN
    included, which ``pyarrow.Table.equals`` counts as unequal to itself)."""

    def stream(table: pa.Table) -> bytes:
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, table.schema) as writer:
            writer.write_table(table.combine_chunks())
        return bytes(sink.getvalue().to_pybytes())

    return bool(a.schema.equals(b.schema, check_metadata=True)) and stream(a) == stream(b)


def equilibria_per_second(run: GridRun) -> float:
    """Equilibria computed by the run per second of its wall time."""
    return run.computed_equilibria / run.elapsed_s if run.elapsed_s > 0 else math.nan
