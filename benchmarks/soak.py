"""Soak: ``canguard run`` for N minutes against a simulated robot, with faults injected at random times.

    python benchmarks/soak.py --minutes 30 [--seed 1] [--json report.json]

The daemon runs as a subprocess (``python -m canguard run``) on python-can's
``udp_multicast`` bus with the whole-robot example config; this process plays the
simulated robot on the same bus (``canguard.sim``: 4 ODrive axes + BMS, and the
``load`` scenario's 40 background ids: about 8,000 frames/s, what a 1 Mbit/s bus
carries) and injects, at seeded random times, one fault after another:

======================  =============================================  ==========================
fault                   what is injected                               expected reaction (bound)
======================  =============================================  ==========================
spike                   one BMS frame at 60 A                          ``trip`` overcurrent on /battery_state
overload                axis0 at 2x its continuous current for 3 s     ``trip`` of the I²t guard
dropout                 no BMS frame for 1.5 s                         ``stale`` /battery_state
garbage                 NaN/inf, wrong-length and random frames        ``trip`` on axis2 (invalid data)
errorburst              32 CAN error frames                            no crash; counted
bad_reload              a config with a mistake, then SIGHUP           ``error`` "reload rejected"
good_reload             the config back, then SIGHUP                   ``reload``
======================  =============================================  ==========================

Each reaction must come within ``--bound`` seconds (default 2.0) of the time the
simulator sent the fault (wall clock): its scheduled time, or later where the simulator,
in this process, fell behind real time on a loaded machine (its clock is read every
0.2 s; the fault is timed from the last reading before it, so a delay is never read short),
and every trip must be followed by a ``stop`` event at the same tick. After the run:
every journal line must parse (none torn, none lost between ``start`` and ``exit``),
the daemon must exit 0 on SIGTERM. The daemon's RSS and CPU are sampled every
``--sample`` seconds; the report gives the RSS growth per third of the run and the
least-squares slope of its last half (``slope_last_half_mb_per_10min``): about 0 means
flat. ``--tracemalloc FRAMES`` runs the daemon under tracemalloc
(``benchmarks/traced_daemon.py``) and adds the traced Python memory, start to end:
RSS that grows while the traced total stays flat is the allocator, not a leak.
Exit status 0 when every check holds.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import json
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
if str(REPO) not in sys.path:  # run as a script: the benchmarks package (and canguard, where not installed)
    sys.path.insert(0, str(REPO))
if importlib.util.find_spec("canguard") is None:
    sys.path.append(str(SRC))

import can  # noqa: E402
import yaml  # noqa: E402

from benchmarks import kit  # noqa: E402
from benchmarks.kit import Options, Table  # noqa: E402
from canguard.config.loader import load_config  # noqa: E402
from canguard.sim import SimRobot, run_on_bus  # noqa: E402

ROBOT = REPO / "config" / "examples" / "robot_guard.yaml"
# onset of each simulator scenario after its @offset (see `canguard simulate -h`), and what must follow
SIM_FAULTS: dict[str, tuple[float, str]] = {
    "spike": (1.51, "trip:/battery_state"),
    "overload": (3.0, "trip:axis0"),
    "dropout": (2.5, "stale:/battery_state"),
    "garbage": (1.0, "trip:axis2"),
    "errorburst": (1.0, ""),
}
HOST_FAULTS = ("bad_reload", "good_reload")
LIGHT_RATES_HZ = {"Get_Iq": 50.0, "Get_Torques": 50.0, "Get_Encoder_Estimates": 20.0}
"""``--light``: each axis's current, torque and encoder streams at these rates (the drives' defaults are 250, 250
and 100 Hz); the BMS, bus-voltage and heartbeat streams as they are: ~650 frames/s without the load."""
SPACING_S = 9.0
"""At least this long between two faults (an overload lasts 5 s; a trip must recover first)."""


@dataclass
class Fault:
    kind: str
    at_s: float  # offset from the robot's start
    expect: str = ""
    wall: float = 0.0
    seen: float | None = None
    detail: str = ""


@dataclass
class Report:
    minutes: float
    faults: list[Fault] = field(default_factory=list)
    samples: list[tuple[float, float, float]] = field(default_factory=list)  # (s, rss MB, cpu %)
    lines: int = 0
    torn: int = 0
    trips: int = 0
    trips_without_stop: int = 0
    exit_code: int | None = None
    frames_sent: int = 0
    trace_dir: str = ""
    sim_lag_s: list[float] = field(default_factory=list)  # wall time minus the simulator's time, at each sample
    sim_clock: list[tuple[float, float]] = field(default_factory=list)  # (wall time, simulator's seconds), 5 Hz


def sent_at(fault: Fault, onset: float, clock: list[tuple[float, float]]) -> float:
    """When the simulator sent ``fault`` (its onset ``onset`` s after the fault's time), in wall time: the
    scheduled time, or, where the simulator ran late, the last reading of its clock before the onset."""
    due = fault.wall + onset
    before = [wall for wall, sim in clock if sim < fault.at_s + onset]
    return max(due, before[-1]) if before else due


def schedule(seed: int, duration_s: float) -> list[Fault]:
    """Faults at random times, SPACING_S apart at least, each kind in turn (shuffled per round)."""
    rng = random.Random(seed)
    kinds = [*SIM_FAULTS, "bad_reload"]
    out: list[Fault] = []
    t = 5.0
    while True:
        rng.shuffle(kinds)
        for kind in kinds:
            t += SPACING_S + rng.uniform(0.0, 6.0)
            if t + 6.0 > duration_s:
                return out
            onset, expect = SIM_FAULTS.get(kind, (0.0, "error:reload rejected"))
            out.append(Fault(kind, t, expect))
            if kind == "bad_reload":
                out.append(Fault("good_reload", t + 2.0, "reload:"))
                t += 2.0
            else:
                out[-1].detail = f"onset +{onset} s"


def write_config(tmp: Path, bus: dict[str, Any]) -> Path:
    doc = yaml.safe_load(ROBOT.read_text(encoding="utf-8"))
    doc["dbc"] = [str((ROBOT.parent / d).resolve()) for d in doc["dbc"]]
    doc["tree"]["file"] = str((ROBOT.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {"main": bus}
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def proc_sample(pid: int, last: tuple[float, float] | None) -> tuple[float, float, tuple[float, float]]:
    """(RSS MB, CPU % since the last sample, state for the next call) from /proc."""
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        rss_kb = next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    ticks = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    now = time.monotonic()
    cpu = 100.0 * (ticks - last[1]) / (now - last[0]) if last else 0.0
    return rss_kb / 1024.0, cpu, (now, ticks)


def read_journal(path: Path) -> tuple[list[dict[str, Any]], int]:
    """(parsed lines, lines that do not parse)."""
    events, torn = [], 0
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            events.append(json.loads(line))
        except json.JSONDecodeError:
            torn += 1
    return events, torn


def check(report: Report, events: list[dict[str, Any]], bound_s: float) -> None:
    """Match each fault with its reaction; count trips without a stop."""
    for fault in report.faults:
        if not fault.expect:
            continue
        kind, _, what = fault.expect.partition(":")
        onset = SIM_FAULTS.get(fault.kind, (0.0, ""))[0]
        due = sent_at(fault, onset, report.sim_clock) if fault.kind in SIM_FAULTS else fault.wall + onset
        for ev in events:
            t = ev.get("t")
            if not isinstance(t, (int, float)) or ev.get("event") != kind or t < due - 0.05:
                continue
            text = f"{ev.get('source')} {ev.get('node')} {ev.get('reason')}"
            if what and what not in text:
                continue
            fault.seen = t - due
            break
    trip_ts = [ev["t"] for ev in events if ev.get("event") == "trip"]
    stop_ts = sorted(ev["t"] for ev in events if ev.get("event") == "stop")
    report.trips = len(trip_ts)
    # a trip while a stop already holds needs no new stop event; one with no stop at or before it does
    report.trips_without_stop = sum(1 for t in trip_ts if not any(s <= t + 1e-6 for s in stop_ts))


def soak(args: argparse.Namespace) -> Report:
    import random as _r

    rnd = _r.SystemRandom()
    bus_kwargs = {"interface": "udp_multicast", "channel": f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}."
                  f"{rnd.randint(1, 254)}", "port": rnd.randint(20000, 60000)}
    tmp = Path(tempfile.mkdtemp(prefix="canguard-soak-"))
    cfg_path = write_config(tmp, bus_kwargs)
    good_text = cfg_path.read_text(encoding="utf-8")
    duration = args.minutes * 60.0
    report = Report(args.minutes, schedule(args.seed, duration))
    env = kit.child_env(args.src)
    cmd = [sys.executable, "-m", "canguard"]
    if args.tracemalloc:
        trace_dir = args.trace_dir or tmp / "trace"
        report.trace_dir = str(trace_dir)
        env.update(CANGUARD_TRACE_DIR=str(trace_dir), CANGUARD_TRACE_FRAMES=str(args.tracemalloc),
                   CANGUARD_TRACE_EVERY=str(args.sample), CANGUARD_TRACE_SNAPS=args.snapshots)
        cmd = [sys.executable, str(REPO / "benchmarks" / "traced_daemon.py")]
    daemon = subprocess.Popen([*cmd, "run", "-c", str(cfg_path)], env=env,
                              stdout=subprocess.DEVNULL, stderr=open(tmp / "daemon.stderr", "w"))  # noqa: SIM115
    events_path = tmp / "events.jsonl"
    deadline = time.monotonic() + 30
    while not (events_path.exists() and b'"start"' in events_path.read_bytes()):
        if time.monotonic() > deadline or daemon.poll() is not None:
            raise SystemExit(f"the daemon did not start: {(tmp / 'daemon.stderr').read_text()[-2000:]}")
        time.sleep(0.1)
    cfg = load_config(cfg_path)
    scenarios = [*(["load"] if args.load else []), *[f"{f.kind}@{f.at_s:.3f}" for f in report.faults
                                                     if f.kind in SIM_FAULTS]]
    robot = SimRobot(db=cfg.database, scenarios=scenarios, seed=args.seed,
                     rates_hz=LIGHT_RATES_HZ if args.light else None)
    bus = can.Bus(**bus_kwargs)
    stop = threading.Event()
    sent: list[int] = []
    start_wall = time.time()
    start_mono = time.monotonic()
    sim0 = robot.now
    for f in report.faults:
        f.wall = start_wall + f.at_s
    player = threading.Thread(target=lambda: sent.append(run_on_bus(bus, duration, robot=robot, stop_event=stop)),
                              daemon=True)
    player.start()
    host = [f for f in report.faults if f.kind in HOST_FAULTS]
    last: tuple[float, float] | None = None
    next_sample = 0.0
    try:
        while player.is_alive():
            elapsed = time.monotonic() - start_mono
            report.sim_clock.append((time.time(), robot.now - sim0))
            while host and host[0].at_s <= elapsed:
                f = host.pop(0)
                bad = good_text.replace("tick_hz: 100", "tick_hz: -5") if f.kind == "bad_reload" else good_text
                cfg_path.write_text(bad, encoding="utf-8")
                daemon.send_signal(signal.SIGHUP)
            if elapsed >= next_sample:
                rss, cpu, last = proc_sample(daemon.pid, last)
                report.samples.append((round(elapsed, 1), round(rss, 1), round(cpu, 1)))
                report.sim_lag_s.append(elapsed - (robot.now - sim0))
                next_sample += args.sample
            if daemon.poll() is not None:
                raise SystemExit(f"the daemon died: {(tmp / 'daemon.stderr').read_text()[-2000:]}")
            time.sleep(0.2)
    finally:
        stop.set()
        player.join(timeout=10)
        bus.shutdown()
        if daemon.poll() is None:
            daemon.send_signal(signal.SIGTERM)
        report.exit_code = daemon.wait(timeout=30)
    report.frames_sent = sent[0] if sent else 0
    events, report.torn = read_journal(events_path)
    report.lines = len(events) + report.torn
    check(report, events, args.bound)
    if events and (events[0].get("event") != "start" or events[-1].get("event") != "exit"):
        report.torn += 1  # the journal must run from start to exit: a missing end is a lost line
    return report


def slope_per_10min(points: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of (seconds, MB) points, in MB per 10 minutes."""
    if len(points) < 2:
        return None
    mx = statistics.fmean(p[0] for p in points)
    my = statistics.fmean(p[1] for p in points)
    sxx = sum((p[0] - mx) ** 2 for p in points)
    if sxx == 0:
        return None
    return 600.0 * sum((p[0] - mx) * (p[1] - my) for p in points) / sxx


def rss_trend(samples: list[tuple[float, float, float]]) -> dict[str, Any]:
    """Growth per third of the run (MB, last sample of a third minus the last of the one before) and
    the least-squares slope of the last half (MB per 10 min): 'is it flat?' answered by one number."""
    if len(samples) < 4:
        return {"growth_per_third_mb": None, "slope_last_half_mb_per_10min": None}
    end = samples[-1][0]
    edges = [samples[0][1]]
    for k in (1, 2, 3):
        edges.append([s[1] for s in samples if s[0] <= end * k / 3][-1])
    half = [(s[0], s[1]) for s in samples if s[0] >= end / 2]
    slope = slope_per_10min(half)
    return {"growth_per_third_mb": [round(b - a, 2) for a, b in itertools.pairwise(edges)],
            "slope_last_half_mb_per_10min": None if slope is None else round(slope, 3)}


def traced_summary(trace_dir: Path) -> dict[str, Any]:
    """The traced_daemon.py figures: traced MB start, end, max; slope of the last half; malloc_trim lines."""
    path = trace_dir / "traced.tsv"
    if not path.exists():
        return {"error": f"no {path}"}
    rows = [[float(x) for x in line.split()] for line in path.read_text(encoding="ascii").splitlines() if line]
    half = [(r[0], r[1]) for r in rows if r[0] >= rows[-1][0] / 2]
    slope = slope_per_10min(half)
    out: dict[str, Any] = {"dir": str(trace_dir), "traced_mb": {
        "start": rows[0][1], "end": rows[-1][1], "max": max(r[1] for r in rows),
        "slope_last_half_mb_per_10min": None if slope is None else round(slope, 3),
        "samples": [[r[0], r[1]] for r in rows]},
        "reader_queue_max": max((int(r[4]) for r in rows if len(r) > 4), default=None),
        "blackboard_keys_start_end": [int(rows[0][5]), int(rows[-1][5])] if len(rows[0]) > 5 else None,
        "rss_minus_tracemalloc_own_mb_start_end": [round(r[3] - r[7], 1) for r in (rows[0], rows[-1])]
        if len(rows[0]) > 7 else None}
    trim = trace_dir / "trim.tsv"
    if trim.exists():
        out["at_exit_rss_before_after_malloc_trim_traced_mb"] = [
            [float(x) for x in line.split()] for line in trim.read_text(encoding="ascii").splitlines() if line]
    return out


def summarize(report: Report, bound_s: float) -> tuple[dict[str, Any], bool]:
    judged = [f for f in report.faults if f.expect]
    late = [f for f in judged if f.seen is None or f.seen > bound_s]
    delays = [f.seen for f in judged if f.seen is not None]
    rss = [s[1] for s in report.samples]
    cpu = [s[2] for s in report.samples[1:]]
    out = {
        "minutes": report.minutes,
        "frames_sent": report.frames_sent,
        "frames_per_s": round(report.frames_sent / (report.minutes * 60.0)) if report.minutes else 0,
        # reactions are timed from when the simulator sent each fault, which is later than scheduled when
        # it falls behind real time on a busy machine (its frames paced late): how far it fell behind
        "simulator_lag_s_max": round(max(report.sim_lag_s, default=0.0), 2),
        "faults": {k: sum(1 for f in report.faults if f.kind == k) for k in [*SIM_FAULTS, *HOST_FAULTS]},
        "reactions_within_bound": f"{len(judged) - len(late)}/{len(judged)} (bound {bound_s} s)",
        "reaction_delay_s": {"median": round(statistics.median(delays), 3) if delays else None,
                             "max": round(max(delays), 3) if delays else None},
        "late_or_missing": [f"{f.kind}@{f.at_s:.1f}: {f.seen}" for f in late],
        "journal_lines": report.lines, "torn_or_lost_lines": report.torn,
        "trips": report.trips, "trips_without_stop": report.trips_without_stop,
        "rss_mb": {"start": rss[0] if rss else None, "end": rss[-1] if rss else None, "max": max(rss, default=None),
                   **rss_trend(report.samples), "samples": [[s[0], s[1]] for s in report.samples]},
        "cpu_percent": {"median": statistics.median(cpu) if cpu else None, "max": max(cpu, default=None)},
        "daemon_exit": report.exit_code,
    }
    if report.trace_dir:
        out["tracemalloc"] = traced_summary(Path(report.trace_dir))
    ok = not late and report.torn == 0 and report.trips_without_stop == 0 and report.exit_code == 0
    return out, ok


def parser() -> argparse.ArgumentParser:
    """soak.py's arguments."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bound", type=float, default=2.0, help="seconds from a fault to its reaction (default 2)")
    ap.add_argument("--sample", type=float, default=10.0, help="seconds between RSS/CPU samples")
    ap.add_argument("--json", type=Path, default=None, help="write the report here too")
    ap.add_argument("--tracemalloc", type=int, default=0, metavar="FRAMES",
                    help="run the daemon under tracemalloc with FRAMES frames per traceback "
                         "(benchmarks/traced_daemon.py): the report adds the traced total")
    ap.add_argument("--trace-dir", type=Path, default=None, help="where --tracemalloc writes (default: the run's tmp)")
    ap.add_argument("--snapshots", default="", metavar="S,S,...",
                    help="with --tracemalloc: seconds after start at which to dump a snapshot")
    ap.add_argument("--no-load", dest="load", action="store_false",
                    help="without the 40 background ids (~2,600 instead of ~8,000 frames/s): a slow machine")
    ap.add_argument("--light", action="store_true",
                    help="the axes' streams at 50/50/20 Hz instead of 250/250/100 (~650 frames/s with --no-load): "
                         "every fault and its reaction as in a full run, at a quarter of the frames (CI's smoke run)")
    ap.add_argument("--src", type=Path, default=SRC, help=argparse.SUPPRESS)  # the canguard tree run
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the soak, print its report; exit 1 when a check fails."""
    args = parser().parse_args(argv)
    kit.clean_up_on_sigterm()  # a killed run stops the daemon and load it started
    report = soak(args)
    out, ok = summarize(report, args.bound)
    text = json.dumps(out, indent=2)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n", encoding="utf-8")
    print("soak: ok" if ok else "soak: FAILED", file=sys.stderr)
    return 0 if ok else 1


def run(opts: Options) -> Table:
    """Suite ``soak``: a soak (3 minutes, the robot's own streams; --quick: 3 s, light) as a table of its checks,
    each beside its bound, worst (closest to its bound) first; a failed check is shown under it (exit 1)."""
    argv = ["--minutes", "0.05", "--light"] if opts.quick else ["--minutes", "3"]
    args = parser().parse_args([*argv, "--no-load", "--sample", "1" if opts.quick else "10", "--src", str(opts.src)])
    out, ok = summarize(soak(args), args.bound)
    rss, delay = out["rss_mb"], out["reaction_delay_s"]
    judged, total = out["reactions_within_bound"].split()[0].split("/")
    rows: list[list[kit.Cell]] = [
        ["slowest reaction to a fault", delay["max"], "bound", args.bound, kit.ratio(delay["max"], args.bound), "s"],
        ["median reaction to a fault", delay["median"], "bound", args.bound, kit.ratio(delay["median"], args.bound),
         "s"],
        ["faults without their reaction in time", int(total) - int(judged), "faults injected", int(total), None, ""],
        ["journal lines torn or lost", out["torn_or_lost_lines"], "journal lines", out["journal_lines"], None, ""],
        ["trips without a stop", out["trips_without_stop"], "trips", out["trips"], None, ""],
        ["daemon RSS at the end", rss["end"], "RSS at the start", rss["start"], kit.ratio(rss["end"], rss["start"]),
         "MB"],
        ["daemon CPU, median of the samples", out["cpu_percent"]["median"], "frames/s sent", out["frames_per_s"],
         None, "% of a core"]]
    rows.sort(key=lambda r: -(r[4] if isinstance(r[4], float) else 0.0))
    notes = [f"{out['frames_per_s']:,} frames/s (the robot's own streams, no background ids); the simulator fell "
             f"behind real time by up to {out['simulator_lag_s_max']} s (faults are timed from when it sent them)",
             f"RSS slope of the last half: {rss.get('slope_last_half_mb_per_10min')} MB per 10 min; daemon exit "
             f"{out['daemon_exit']}; the 30-minute soak at 8,000 frames/s: `python benchmarks/soak.py --minutes 30 "
             "--sample 30`"]
    if opts.quick:
        notes.append("--quick: 3 s, light rates, no load, no fault due yet: checks that the suite runs")
    return Table("soak", f"`canguard run` for {args.minutes:g} min against the simulated robot with faults injected "
                 f"(seed {args.seed}); every check beside its bound", ["check", "canguard", "peer / bound",
                                                                        "peer figure", "canguard / bound", "unit"],
                 rows, notes, costs=["canguard"],
                 failed="" if ok else failure(out))


def failure(out: dict[str, Any]) -> str:
    """What a failed soak failed, in one line."""
    return (f"late or missing: {', '.join(out['late_or_missing']) or '-'}; journal lines torn "
            f"{out['torn_or_lost_lines']}, trips without a stop {out['trips_without_stop']}, daemon exit "
            f"{out['daemon_exit']}")


if __name__ == "__main__":
    sys.exit(main())
