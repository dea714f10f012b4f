"""
The fleet run on Ray: one actor per worker, one task per bag (or per time range of a long bag).

:func:`run_fleet` starts an embedded local Ray sized to the machine (or joins a running cluster
by address), starts one :class:`~mvbb_ros.fleet.tasks.BagWorker` actor per worker (each loads
the compiled kernels once and keeps them), and keeps every actor busy with the next task. Ray
places the actors, restarts one whose process dies and runs its task again
(``max_restarts``/``max_task_retries``); the outputs are atomic, so a retried bag is written
once, complete. Bags whose outputs are complete with the same settings hash are skipped (their
rows come from their manifests). Inputs and the output folder must be visible to every worker
at the same paths (one machine, or a shared file system on a cluster).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
import contextlib
from dataclasses import dataclass, field, replace
import logging
import os
from pathlib import Path
import shutil
import tempfile
import time
from typing import Any

from mvbb_ros.common.progress import ProgressBar
from mvbb_ros.fleet.inputs import bag_names, Setting
from mvbb_ros.fleet.summary import SummaryPaths, write_summary
from mvbb_ros.fleet.tasks import (
    BagJob,
    BagWorker,
    cloud_topic,
    completed_rows,
    completed_skipped,
    completed_storage_error,
    Outcome,
    plan_ranges,
    remove_leftovers,
    settings_digest,
    STAGING,
    TimeRange,
)
from mvbb_ros.ros.bag import BagError, CloudBag

#: Times Ray runs a task again after its worker process died.
DEFAULT_RETRIES = 3
#: Bags with more clouds than this are cut into time ranges of about this many clouds.
DEFAULT_CLOUDS_PER_RANGE = 300


class FleetError(Exception):
    """The run cannot start (the output folder, the cluster): the message says why."""


@dataclass
class BagReport:
    """
    One bag under one setting, at the end of the run.

    :ivar status: ``processed``, ``resumed`` (complete from an earlier run) or ``failed``.
    :ivar error: why it failed ('' otherwise).
    :ivar retries: how many times Ray ran one of its tasks again.
    :ivar ranges: time ranges it was cut into (1: one task).
    :ivar reruns: ranges run again because the grasp memory rebuilt at their start differed.
    :ivar skipped: the messages skipped because they do not deserialize
        (:func:`~mvbb_ros.fleet.tasks.skipped_entry`).
    :ivar storage_error: where the bag's storage failed partway ('' when it did not); its
        output holds the clouds before it, as `bag process` writes them.
    """

    job: BagJob
    status: str = 'processed'
    error: str = ''
    rows: list[dict[str, Any]] = field(default_factory=list)
    retries: int = 0
    ranges: int = 1
    reruns: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    skipped: list[dict[str, Any]] = field(default_factory=list)
    storage_error: str = ''


@dataclass
class FleetResult:
    """The run's bags, its wall time, its workers and where the summary went."""

    reports: list[BagReport]
    wall_seconds: float
    workers: int
    start_time: float
    summary: SummaryPaths | None = None

    @property
    def failed(self) -> list[BagReport]:
        """Return the bags that failed."""
        return [report for report in self.reports if report.status == 'failed']

    @property
    def truncated(self) -> list[BagReport]:
        """Return the bags whose storage failed partway (their outputs hold what came before)."""
        return [report for report in self.reports if report.storage_error]

    @property
    def busy_seconds(self) -> tuple[float, float]:
        """Return the workers' task seconds: wall clock and CPU (their ratio: the CPU share)."""
        processed = [r for r in self.reports if r.status != 'resumed']
        return sum(r.seconds for r in processed), sum(r.cpu_seconds for r in processed)

    @property
    def clouds(self) -> int:
        """Return the clouds processed in this run (not the resumed ones)."""
        return sum(len(r.rows) for r in self.reports if r.status == 'processed')

    @property
    def skipped(self) -> int:
        """Return the messages skipped as corrupt in the bags of this run (not the resumed)."""
        return sum(len(r.skipped) for r in self.reports if r.status == 'processed')


def check_output_folder(output: Path) -> None:
    """
    Create `output` if needed and check that files can be written in it.

    :raises FleetError: saying why not.
    """
    try:
        output.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=output, prefix='.write-check.'):
            pass
    except OSError as error:
        reason = error.strerror or str(error)
        raise FleetError(f'cannot write to the output folder {output}: {reason}') from error


def make_jobs(
    bags: Sequence[Path], grid: Sequence[Setting], output: Path, options: dict[str, Any]
) -> list[BagJob]:
    """Return one job per bag and setting (``DIR/<bag>`` or ``DIR/<setting>/<bag>``)."""
    names = bag_names(bags)
    jobs = []
    for setting in grid:
        folder = output / setting.label if setting.label else output
        for bag, name in zip(bags, names, strict=True):
            try:
                digest = settings_digest(bag, setting.settings, options)
            except OSError:
                digest = ''
            jobs.append(
                BagJob(bag, name, setting.label, folder / name, setting.settings, options, digest)
            )
    return jobs


def _start_ray(cluster: str, workers: int | None) -> tuple[Any, int]:
    """Start or join Ray; return the module and the number of workers to start."""
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')
    import ray  # only the fleet loads Ray

    local = not cluster
    try:
        if local:
            cpus = os.cpu_count() or 1
            count = min(workers, cpus) if workers else cpus
            ray.init(
                num_cpus=count,
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.ERROR,
                object_store_memory=256 * 1024 * 1024,
            )
        else:
            ray.init(address=cluster, log_to_driver=False, logging_level=logging.ERROR)
            cpus = int(ray.cluster_resources().get('CPU', 1))
            count = min(workers, cpus) if workers else cpus
    except Exception as error:  # Ray raises ConnectionError, RuntimeError, ValueError
        where = 'the local Ray' if local else f'the Ray cluster at {cluster}'
        raise FleetError(f'cannot start {where}: {error}') from error
    return ray, max(1, count)


class _Driver:
    """The dispatch loop: actors, tasks in flight, and each split bag's ranges."""

    def __init__(self, ray: Any, workers: int, retries: int, bar: ProgressBar) -> None:
        self.ray = ray
        remote = ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=retries)(BagWorker)
        self.actors = [remote.remote() for _ in range(workers)]
        ray.get([actor.ready.remote() for actor in self.actors])
        self.idle = list(self.actors)
        self.queue: deque[tuple[Any, ...]] = deque()
        self.pending: dict[Any, tuple[Any, tuple[Any, ...]]] = {}
        self.ranges: dict[int, dict[str, Any]] = {}
        self.bar = bar
        self.done = 0

    def submit_all(self) -> None:
        while self.queue and self.idle:
            task = self.queue.popleft()
            actor = self.idle.pop()
            kind, report = task[0], task[1]
            if kind == 'bag':
                ref = actor.process.remote(report.job)
            elif kind == 'range':
                ref = actor.process_range.remote(report.job, task[2])
            else:
                ref = actor.assemble.remote(report.job, task[2], task[3], task[4])
            self.pending[ref] = (actor, task)

    def finish(self, report: BagReport) -> None:
        self.done += 1
        self.bar.update(self.done, f'last: {report.job.name} ({len(report.rows)} clouds)')

    def outcome(self, ref: Any) -> tuple[tuple[Any, ...], Outcome]:
        actor, task = self.pending.pop(ref)
        self.idle.append(actor)
        try:
            outcome = self.ray.get(ref)
        except self.ray.exceptions.RayError as error:  # the worker died more often than retried
            reason = str(error).strip().splitlines()[0] if str(error).strip() else repr(error)
            outcome = Outcome(error=f'worker lost: {reason}')
        return task, outcome

    def handle(self, task: tuple[Any, ...], outcome: Outcome) -> None:
        kind, report = task[0], task[1]
        report.retries += max(0, outcome.attempts - 1)
        report.seconds += outcome.seconds
        report.cpu_seconds += outcome.cpu_seconds
        if kind == 'range':
            self._range_done(report, task[2], outcome)
            return
        if outcome.error:
            report.status, report.error = 'failed', outcome.error
        else:
            report.rows, report.skipped = outcome.rows, outcome.skipped
            report.storage_error = outcome.storage_error
        self.finish(report)

    def run_whole(self, report: BagReport) -> None:
        """
        Give up a bag's ranges and run it as one task (its storage fails partway).

        A serial `bag process` stops at the first message the storage cannot give; ranges after
        it may read on, and one range cannot know how many clouds the others read. The whole bag
        through `process_bag` stops where the serial run stops, with its bytes. The report keeps
        the number of ranges it was cut into (the summary's ``ranges``).
        """
        self.ranges[id(report)]['failed'] = True  # outcomes of ranges still running are dropped
        self.queue.appendleft(('bag', report))

    def _range_done(self, report: BagReport, span: TimeRange, outcome: Outcome) -> None:
        state = self.ranges[id(report)]
        if state['failed']:
            return
        if outcome.error:
            state['failed'] = True
            report.status, report.error = 'failed', outcome.error
            self.finish(report)
            return
        if outcome.storage_error:
            self.run_whole(report)
            return
        state['outcomes'][span.number] = (span, outcome)
        spans, outcomes = state['spans'], state['outcomes']
        while state['verified'] + 1 < len(spans) and state['verified'] + 1 in outcomes:
            number = state['verified'] + 1
            done_span, done = outcomes[number]
            if number > 0:
                previous = outcomes[number - 1][1].end_memory
                if done.start_memory != previous:  # the warm-up did not rebuild the memory
                    del outcomes[number]
                    report.reruns += 1
                    self.queue.appendleft(('range', report, replace(done_span, memory=previous)))
                    return
            state['verified'] = number
        if state['verified'] + 1 == len(spans):
            rows = [row for number in range(len(spans)) for row in outcomes[number][1].rows]
            skipped = [
                item for number in range(len(spans)) for item in outcomes[number][1].skipped
            ]
            if len(rows) + len(skipped) < state['count']:  # the index lists messages not there
                self.run_whole(report)
                return
            self.queue.appendleft(('assemble', report, len(spans), rows, skipped))

    def run(self) -> None:
        while self.queue or self.pending:
            self.submit_all()
            ready, _ = self.ray.wait(list(self.pending), num_returns=1)
            for ref in ready:
                self.handle(*self.outcome(ref))


def run_fleet(
    bags: Sequence[Path],
    grid: Sequence[Setting],
    output: Path,
    *,
    options: dict[str, Any] | None = None,
    cluster: str = '',
    workers: int | None = None,
    retries: int = DEFAULT_RETRIES,
    clouds_per_range: int = DEFAULT_CLOUDS_PER_RANGE,
    progress: bool | None = None,
    picture: bool = True,
    log: Callable[[str], object] = print,
) -> FleetResult:
    """
    Process every bag under every setting of `grid` on Ray; write each output and the summary.

    :param bags: the input bags (:func:`~mvbb_ros.fleet.inputs.expand_inputs`).
    :param grid: the settings (:func:`~mvbb_ros.fleet.inputs.sweep_settings`).
    :param output: the output folder.
    :param options: ``topics`` (the cloud topics to look for, in order), and `process_bag`'s
        namespace, storage and compress.
    :param cluster: '' for an embedded local Ray, else a running cluster's address.
    :param workers: at most this many workers (None: one per CPU of the machine or cluster).
    :param retries: times a task runs again after its worker process died.
    :param clouds_per_range: bags with more clouds are cut into time ranges of about this many.
    :param progress: progress bar over the bags (None: when stderr is a terminal).
    :param picture: also draw ``summary.png``.
    :param log: where the run's messages go.
    :raises FleetError: when the output folder cannot be written or Ray cannot start.
    """
    start_time, start = time.time(), time.perf_counter()
    options = dict(options or {})
    check_output_folder(output)
    jobs = make_jobs(bags, grid, output, options)
    reports = [BagReport(job) for job in jobs]
    bar = ProgressBar(len(reports), label='fleet', enabled=progress)
    todo: list[BagReport] = []
    for report in reports:
        job = report.job
        if not job.bag.exists():
            report.status, report.error = 'failed', f'bag not found: {job.bag}'
        elif (rows := completed_rows(job)) is not None:
            report.status, report.rows = 'resumed', rows
            report.skipped = completed_skipped(job)
            report.storage_error = completed_storage_error(job)
        else:
            todo.append(report)
    skipped = len(reports) - len(todo)
    resumed = sum(1 for report in reports if report.status == 'resumed')
    if resumed:
        log(f'{resumed} bag outputs complete with the same settings: skipped')
    ray: Any = None
    count = 0
    try:
        if todo:
            ray, count = _start_ray(cluster, workers)
            log(f'{len(todo)} bag runs on {count} Ray workers')
            driver = _Driver(ray, count, retries, bar)
            driver.done = skipped
            # The biggest bags first, so that no long bag starts last and runs alone.
            for report in sorted(todo, key=lambda r: -_input_bytes(r.job.bag)):
                remove_leftovers(report.job)
                _plan(report, driver, clouds_per_range)
            driver.run()
    except KeyboardInterrupt:
        # Disconnecting ends the actors (their owner is gone) and an embedded Ray with them;
        # every output is renamed into place only when complete, so what is left is complete.
        bar.close()
        if ray is not None:
            with contextlib.suppress(Exception):
                ray.shutdown()
        for report in todo:
            remove_leftovers(report.job)
        raise
    bar.close()
    if ray is not None:
        ray.shutdown()
    for report in todo:
        remove_leftovers(report.job)
    _remove_empty_staging(output)
    result = FleetResult(reports, time.perf_counter() - start, count, start_time)
    result.summary = write_summary(result, output, picture=picture)
    return result


def _plan(report: BagReport, driver: _Driver, clouds_per_range: int) -> None:
    """Queue a bag as one task, or as time ranges when it is long and its storage whole."""
    job = report.job
    try:
        with CloudBag(job.bag) as bag:
            topic = cloud_topic(bag, job.options.get('topics', ()))
            # A storage file known to be cut short is read from its start: one task.
            spans = [] if bag.salvaged else plan_ranges(bag, topic, clouds_per_range)
            count = bag.count([topic])
    except BagError:
        spans = []  # the worker reports the problem, as a serial `bag process` would
    if len(spans) <= 1:
        driver.queue.append(('bag', report))
        return
    report.ranges = len(spans)
    driver.ranges[id(report)] = {
        'spans': spans,
        'outcomes': {},
        'verified': -1,
        'failed': False,
        'count': count,  # the clouds the bag's index lists on the topic
    }
    driver.queue.extend(('range', report, span) for span in spans)


def _input_bytes(path: Path) -> int:
    files = path.rglob('*') if path.is_dir() else [path]
    return sum(item.stat().st_size for item in files if item.is_file())


def _remove_empty_staging(output: Path) -> None:
    staging = output / STAGING
    if staging.is_dir():
        for folder in sorted(staging.rglob('*'), reverse=True):
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        if not any(staging.iterdir()):
            shutil.rmtree(staging)
