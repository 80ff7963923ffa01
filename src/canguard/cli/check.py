"""What ``canguard check`` prints: the config as canguard understood it."""

from __future__ import annotations

from collections.abc import Iterable

from canguard.config.schema import Config, FrameSpec, SignalRef


def _id(frame_id: int, extended: bool) -> str:
    return f"0x{frame_id:08X} (extended)" if extended else f"0x{frame_id:03X}"


def _signal(ref: SignalRef) -> str:
    text = f"{ref.role} = {ref.signal}" + (f" {ref.unit}" if ref.unit else "")
    if ref.minimum is None and ref.maximum is None:
        return text
    lo = "-inf" if ref.minimum is None else f"{ref.minimum:g}"
    hi = "inf" if ref.maximum is None else f"{ref.maximum:g}"
    return f"{text} [{lo} .. {hi}]"


def _frames(title: str, frames: Iterable[FrameSpec]) -> list[str]:
    lines = [f"    {f.label:<28} bus {f.bus}  id {_id(f.arbitration_id, f.is_extended_id)}{' fd' if f.is_fd else ''}"
             f"  data {f.data.hex(' ') if f.data else '(empty)'}" for f in frames]
    return [f"  {title}:", *lines] if lines else [f"  {title}: (none)"]


def _dbc_notes(notes: tuple[str, ...], verbose: bool) -> list[str]:
    """What the DBC files get wrong where the config does not read it: counted, or (``-v``) one line each."""
    if not notes:
        return []
    notes_word = "note" if len(notes) == 1 else "notes"
    head = f"  {len(notes)} DBC {notes_word} (parts skipped or signals taken out, none read by this config"
    if not verbose:
        return [f"{head}; check -v lists them)"]
    return [f"{head}):", *(f"    {note}" for note in notes)]


def describe(cfg: Config, verbose: bool = False) -> str:
    """The text ``canguard check`` prints for a config that loaded without errors (``verbose``: ``check -v``)."""
    n_messages = len(cfg.database.messages) if cfg.database is not None else 0
    lines = [f"config {cfg.path}", "dbc:", *(f"  {p}" for p in cfg.dbc_files), f"  ({n_messages} messages)",
             *_dbc_notes(cfg.dbc_notes, verbose), "buses:"]
    for name, bus in cfg.buses.items():
        more = "".join(f", {k}={v!r}" for k, v in bus.kwargs.items() if k not in ("interface", "channel"))
        every = "" if bus.filter else "; filter: false (every frame received)"
        lines.append(f"  {name}: interface {bus.interface}, channel {bus.channel}{more}{every}")
    if cfg.canopen:
        lines.append("canopen:")
        for drive in cfg.canopen.values():
            lines += [f"  {line}" for line in drive.describe(verbose)]

    lines += ["sources:", *([] if cfg.sources else ["  (none)"])]
    for name, src in cfg.sources.items():
        lines.append(f"  {name} ({src.kind}, bus {src.bus}, max_age {src.max_age_s:g} s)")
        by_message: dict[tuple[str, str], list[SignalRef]] = {}
        for ref in src.signals:
            by_message.setdefault((ref.bus, ref.message), []).append(ref)
        for (ref_bus, message), refs in by_message.items():
            first = refs[0]
            where = "" if ref_bus == src.bus else f" on bus {ref_bus}"
            lines.append(f"    -> {message} id {_id(first.frame_id, first.is_extended_id)}{where}")
            lines += [f"       {_signal(r)}" for r in refs]
        if src.kind == "battery" and src.signal("present") is None:
            lines.append("       present = (a valid frame arrived)")

    tree = cfg.tree
    lines.append(f"tree: {tree.file} main {tree.main or '(main_tree_to_execute)'}, {tree.tick_hz:g} Hz"
                 if tree is not None else "tree: (none)")
    lines += [f"task: every {cfg.task.period_s:g} s", *_frames("frames", cfg.task.frames),
              f"stop: repeat every {cfg.stop.repeat_s:g} s", *_frames("frames", cfg.stop.frames)]
    c = cfg.stop.confirm
    if c is not None:
        lines.append(f"  confirm: {c.source}.{c.signal} {c.op} {c.value:g} within {c.deadline_s:g} s")
    if c is not None or cfg.stop.escalate:
        lines += _frames("escalate", cfg.stop.escalate)
    lines += ["actions:", *([] if cfg.actions else ["  (none)"])]
    for name, action in cfg.actions.items():
        lines += _frames(name, action.frames)
    st = cfg.state
    lines += [f"events: {cfg.events or '(none)'}",
              f"state: {st.file or '(not kept)'}, on_corrupt {st.on_corrupt}, saved every {st.save_period_s:g} s"]
    return "\n".join(lines)
