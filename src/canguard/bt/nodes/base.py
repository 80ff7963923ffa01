"""What every canguard node shares: typed ports under BT.CPP's names, the context, a load-time ``bind()``."""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterable, Iterator, Mapping
from contextlib import suppress
from typing import TYPE_CHECKING, Any, ClassVar, Literal, TypeVar

import py_trees
from py_trees.blackboard import Blackboard
from py_trees.ports import CONST_PREFIX, NoDataAvailable, PortInformation, PortsMixin
from py_trees.ports_utils import PortsLogger

from canguard.bt.context import Context
from canguard.bt.scripting import ScriptError
from canguard.bt.wakeup import WakeUpSignal
from canguard.errors import quote

if TYPE_CHECKING:
    from canguard.bt.scopes import TreeBlackboard
    from canguard.bt.scripting.script import Script

NodeKind = Literal["Action", "Condition", "Control", "Decorator"]

SUCCESS = py_trees.common.Status.SUCCESS
FAILURE = py_trees.common.Status.FAILURE
RUNNING = py_trees.common.Status.RUNNING
INVALID = py_trees.common.Status.INVALID
Status = py_trees.common.Status
Children = list[py_trees.behaviour.Behaviour] | None
B = TypeVar("B", bound=py_trees.behaviour.Behaviour)

SKIPPED = "SKIPPED"
"""BT.CPP 4's SKIPPED, which py_trees lacks: the node stays IDLE (INVALID) and sets its ``skipped`` flag,
which the parent clears before ticking it (:func:`tick_child`) and reads after (:func:`outcome`)."""
STATUS_NAMES = ("SUCCESS", "FAILURE", "RUNNING", SKIPPED)


def outcome(node: py_trees.behaviour.Behaviour) -> Status | str:
    """What ``node`` returned to its parent in the tick just done: its status, or :data:`SKIPPED`."""
    return SKIPPED if getattr(node, "skipped", False) else node.status


def tick_child(child: py_trees.behaviour.Behaviour) -> Iterator[py_trees.behaviour.Behaviour]:
    """Tick ``child`` (a generator, as py_trees ticks), its skipped flag cleared first."""
    child.skipped = False  # type: ignore[attr-defined]
    yield from child.tick()


def mark_skipped(node: py_trees.behaviour.Behaviour) -> None:
    """``node`` returns SKIPPED: back to IDLE (halted if it was RUNNING, as BT.CPP's ``_while``), flag set."""
    if node.status != INVALID:
        node.stop(INVALID)
    node.skipped = True  # type: ignore[attr-defined]


def end_as(node: B, result: Status | str) -> B:
    """``node`` returns ``result`` (one of :data:`STATUS_NAMES`): RUNNING set, a completion stopped, SKIPPED marked."""
    if result == SKIPPED:
        mark_skipped(node)
    elif Status(result) == RUNNING:
        node.status = RUNNING
    else:
        node.stop(Status(result))
    return node


def count_of(node: py_trees.behaviour.Behaviour, port: str, default: int) -> int:
    """A count port of a parallel node; a negative one is children + 1 + n (so -1 = all)."""
    value = node.port(port)  # type: ignore[attr-defined]
    value = default if value is None else int(value)
    return max(len(node.children) + value + 1, 0) if value < 0 else value


def reset(children: Iterable[py_trees.behaviour.Behaviour]) -> None:
    """Every one of ``children`` back to IDLE (BT.CPP's ``resetChildren``: a new run starts from IDLE)."""
    for child in children:
        if child.status != INVALID:
            child.stop(INVALID)


def follow(node: py_trees.composites.Composite, child: py_trees.behaviour.Behaviour) -> Iterator[Any]:
    """Tick ``child`` and give ``node`` what it returned (RUNNING, SUCCESS, FAILURE or SKIPPED)."""
    node.current_child = child
    yield from tick_child(child)
    yield end_as(node, outcome(child))


def run_script(node: py_trees.behaviour.Behaviour, attr: str, script: Script, board: TreeBlackboard,
               *, condition: bool = False) -> object:
    """Run ``node``'s script ``attr`` on ``board``: its value (``condition``: as a boolean). A ScriptError is
    noted on the node (feedback, ``script_error`` for ``canguard tree --tick``) and raised again."""
    try:
        return script.condition(board) if condition else script.run(board)
    except ScriptError as exc:
        node.feedback_message = f"{attr}: {exc}"
        node.script_error = f"{attr} {script.text!r}: {exc}"  # type: ignore[attr-defined]
        raise


_MISSING = object()
BOOL_TEXT = {"true": True, "false": False, "1": True, "0": False}
"""Texts of a bool as BT.CPP reads them."""


def _number_as(expected: Any, value: Any) -> Any:
    """BT.CPP's casts on reading a port: a real 0/1 (a script's true/false) on a bool port, an integral real on
    an int port, a string entry parsed to the port's type (``convertFromString``); None when there is none."""
    if isinstance(value, str) and expected in (int, float, bool) and "_" not in value:
        text = value.strip()
        try:
            return BOOL_TEXT[text.lower()] if expected is bool else expected(text)
        except (KeyError, ValueError):
            return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if expected is str:  # BT.CPP's Any to string: std::to_string, so reals with %f
        return f"{value:f}" if isinstance(value, float) else str(value)
    if expected is bool and value in (0, 1):
        return bool(value)
    if expected is int and isinstance(value, float) and value.is_integer():
        return int(value)
    return None


def node_kind(cls: type) -> NodeKind:
    """Action, Condition, Control or Decorator: ``KIND`` for a Condition, else from the py_trees base class."""
    if getattr(cls, "KIND", None) == "Condition":
        return "Condition"
    if issubclass(cls, py_trees.decorators.Decorator):
        return "Decorator"
    return "Control" if issubclass(cls, py_trees.composites.Composite) else "Action"


def port_table(cls: type[PortsMixin]) -> dict[str, tuple[str, PortInformation]]:
    """Every port of a node class as ``{name: ("input" | "output", info)}``, inputs first."""
    return {**{n: ("input", i) for n, i in cls.input_ports().items()},
            **{n: ("output", i) for n, i in cls.output_ports().items()}}


class PortError(ValueError):
    """A port value a node cannot work with; the loader turns it into a TreeError naming file and line."""

    def __init__(self, port: str, message: str) -> None:
        self.port = port
        self.message = message
        super().__init__(f"port {port}: {message}")


def port_info(data_type: Any, description: str, default: Any = None, required: bool | None = None) -> PortInformation:
    """A :class:`PortInformation`; required unless it has a default (or ``required=False``)."""
    required = default is None if required is None else required
    return PortInformation(data_type=data_type, required=required, description=description, default_value=default)


class CanguardNode(PortsMixin, register=False):
    """Mixin of every canguard node (combine with a py_trees Behaviour / Decorator / Composite)."""

    KIND: ClassVar[NodeKind] = "Action"
    """The BT.CPP node category (Groot2 palette): see :func:`node_kind`."""
    INPUT_PORTS: dict = {}  # noqa: RUF012 - py_trees reads ports as plain class dicts
    OUTPUT_PORTS: dict = {}  # noqa: RUF012
    DESCRIPTION: ClassVar[str] = ""
    """One line for the Groot2 palette: the class docstring's first paragraph unless set."""
    CONST_PORTS: ClassVar[frozenset[str]] = frozenset()
    """Input ports read once at load time: a ``{key}`` there is a load-time error."""
    KEY_PORTS: ClassVar[frozenset[str]] = frozenset()
    """Input ports that must be wired to a ``{key}``."""
    board: TreeBlackboard  # its scope's blackboard, given by the loader (scripts, SetBlackboard)
    UNTYPED_PORTS: ClassVar[frozenset[str]] = frozenset()
    """Ports of any type (BT.CPP's ``AnyTypeAllowed``): they neither fix nor check their entry's type."""
    CHOICES: ClassVar[Mapping[str, tuple[str, ...]]] = {}
    """Allowed values of string ports, checked at load time for constants."""
    QUIET_RETICK: ClassVar[bool] = False
    """Ticking the node again with the same inputs and children changes nothing and answers as before (no
    timer, counter, memory or output of its own): the engine may count such a tick (:mod:`canguard.engine.quiet`)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        # Stay out of py_trees' global auto-registry: canguard's parser gets an explicit,
        # closed registry, and importing canguard must not change anybody else's "auto".
        kwargs.setdefault("register", False)
        if kwargs["register"] or "tag" in kwargs or cls.INPUT_PORTS.keys() & cls.OUTPUT_PORTS.keys():
            super().__init_subclass__(**kwargs)  # py_trees' own: its registry, or its error
        else:
            # Unregistered, PortsMixin's only work is the check above, behind a slow dir()-wide scan.
            del kwargs["register"]
            super(PortsMixin, cls).__init_subclass__(**kwargs)
        if "DESCRIPTION" not in cls.__dict__ and cls.__doc__:
            cls.DESCRIPTION = " ".join(cls.__doc__.split("\n\n")[0].split())
        cls.KIND = node_kind(cls)
        if issubclass(cls, py_trees.behaviour.Behaviour) and cls.KIND in ("Action", "Condition"):
            # a leaf: py_trees' tick and stop, step for step, without their eager debug strings
            if cls.tick is py_trees.behaviour.Behaviour.tick:
                cls.tick = _leaf_tick  # type: ignore[method-assign]
            if cls.stop is py_trees.behaviour.Behaviour.stop:
                cls.stop = _leaf_stop  # type: ignore[method-assign]
        if issubclass(cls, py_trees.decorators.Decorator) and not getattr(cls.tick, "skip_aware", False):
            cls.tick = _skip_through(cls.tick)  # type: ignore[method-assign,assignment]

    def __init__(self, *args: Any, context: Context, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.ctx = context  # the tree's context (clock, sources, sink, task, events)
        self._dynamic: frozenset[str] = frozenset()
        self._static: dict[str, Any] = {}
        self._wired: frozenset[str] = frozenset()
        self._keys: dict[str, str] = {}
        self._bad_port = ""
        self.skipped = False  # the last tick returned SKIPPED
        self.wake_up = WakeUpSignal()  # the loader gives it the tree's (BT.CPP's setWakeUpInstance)

    def setup_ports(self, port_remappings: dict | None = None, subtree_namespace: str = "/",
                    logger: PortsLogger | None = None) -> None:
        """Register the ports (py_trees), then cache constants and note which ports are wired."""
        super().setup_ports(port_remappings, subtree_namespace, logger)
        remap = port_remappings or {}
        self._dynamic = frozenset(p for p in self.input_ports() if p in remap and CONST_PREFIX not in remap[p])
        self._wired = frozenset(p for p in self.output_ports() if p in remap)
        self._keys = {}
        for port in self._dynamic | self._wired:
            key = self._get_blackboard_key(port)
            last = key.rsplit("/", 1)[-1]  # {@key}: the root's entry from any depth (py_trees gives /Sub/@key)
            self._keys[port] = "/" + last[1:] if last.startswith("@") else key
        self._static = {}
        for name in self.input_ports().keys() - self._dynamic:
            with suppress(NoDataAvailable):  # an optional port left out: reads give None
                self._static[name] = self.get_input(name)

    def is_wired(self, name: str) -> bool:
        """True when the port was given in the XML as a ``{key}`` (input) or at all (output)."""
        return name in self._dynamic or name in self._wired

    def wired_keys(self) -> dict[str, str]:
        """The storage key of every port wired to a ``{key}`` (inputs) or given (outputs), by port name."""
        return dict(self._keys)

    def port(self, name: str) -> Any:
        """The value of input port ``name``: cached constant/default, or the blackboard's at tick, cast as
        BT.CPP does (:func:`_number_as`); None when a wired key holds nothing or a wrong type (``_bad_port``)."""
        if name not in self._dynamic:
            return self._static.get(name)
        value = Blackboard.storage.get(self._keys[name], _MISSING)
        if value is _MISSING:
            info = self.input_ports()[name]
            return info.default_value if info.has_default else None
        expected = self.input_ports()[name].data_type
        if isinstance(value, expected) and (expected is bool or not isinstance(value, bool)):
            return value
        if expected is float and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        converted = _number_as(expected, value)
        if converted is not None:
            return converted
        self._bad_port = f"{name}={value!r} is not {getattr(expected, '__name__', expected)}"
        return None

    def write(self, name: str, value: Any) -> None:
        """Write output port ``name`` when it is wired (a no-op otherwise, as in BehaviorTree.CPP)."""
        if name in self._wired:
            Blackboard.storage[self._keys[name]] = value

    def bind(self) -> None:
        """Load-time set-up from the ports (models, sources); raise :class:`PortError` on bad values."""


def _leaf_tick(self: py_trees.behaviour.Behaviour) -> Iterator[py_trees.behaviour.Behaviour]:
    """py_trees' ``Behaviour.tick`` of a leaf, its debug lines formatted only when they would print."""
    if py_trees.logging.level < py_trees.logging.Level.INFO:  # py_trees' own module-wide level
        self.logger.debug(f"{self.__class__.__name__}.tick()")
    if self.status != RUNNING:
        self.initialise()
    new_status = self.update()
    if type(new_status) is not Status:
        self.logger.error(f"A behaviour returned an invalid status, setting to INVALID [{new_status}][{self.name}]")
        new_status = INVALID
    if new_status != RUNNING:
        self.stop(new_status)
    self.status = new_status
    yield self


def _skip_through(
    tick: Callable[[Any], Iterator[py_trees.behaviour.Behaviour]],
) -> Callable[[Any], Iterator[py_trees.behaviour.Behaviour]]:
    """A decorator's tick with BT.CPP's rule: a SKIPPED child makes it SKIPPED (unless ``SKIP_THROUGH = False``:
    it then sees the child IDLE)."""

    def skip_aware_tick(self: Any) -> Iterator[py_trees.behaviour.Behaviour]:
        child = self.decorated
        child.skipped = False
        self.skipped = False
        if not getattr(self, "SKIP_THROUGH", True):
            yield from tick(self)
            return
        inner = tick(self)
        assert isinstance(inner, Generator)
        for node in inner:
            if node is child and getattr(child, "skipped", False):
                inner.close()
                mark_skipped(self)
                yield self
                return
            yield node

    skip_aware_tick.skip_aware = True  # type: ignore[attr-defined]
    skip_aware_tick.__doc__ = tick.__doc__
    return skip_aware_tick


def _leaf_stop(self: py_trees.behaviour.Behaviour, new_status: Status) -> None:
    """:meth:`py_trees.behaviour.Behaviour.stop` of a leaf (see :func:`_leaf_tick`)."""
    if py_trees.logging.level < py_trees.logging.Level.INFO:
        self.logger.debug(f"{self.__class__.__name__}.stop({new_status})")
    self.terminate(new_status)
    self.status = new_status
    self.iterator = self.tick()


def halted(node: py_trees.behaviour.Behaviour, new_status: py_trees.common.Status) -> bool:
    """True when ``terminate(new_status)`` is a BT.CPP *halt*: a RUNNING node interrupted (not a finished one reset)."""
    return new_status == INVALID and node.status == RUNNING


def node_types(base: type, module: str, rows: Mapping[str, Mapping[str, Any]]) -> tuple[Any, ...]:
    """Node types that differ from ``base`` by class data only: one per row (node ID -> class attributes)."""
    return tuple(type(node_id, (base,), {"__module__": module, "__doc__": f"BT.CPP {node_id}.", **attrs})
                 for node_id, attrs in rows.items())


class DecoratorNode(CanguardNode, py_trees.decorators.Decorator):
    """A canguard decorator; unless it says otherwise its status is its child's."""

    def update(self) -> Status:
        """The child's status."""
        return self.decorated.status


# -- BehaviorTree.CPP 4's pre- and post-conditions on any node -----------------------------------------------
# A script that fails while it runs fails the node, fail-safe (BT.CPP throws); one in _onHalted is only reported.

CONDITIONS = ("_failureIf", "_successIf", "_skipIf", "_while", "_onSuccess", "_onFailure", "_post", "_onHalted")
"""BT.CPP's pre-conditions, then its post-conditions."""


def take_conditions(attrib: dict[str, str]) -> tuple[dict[str, Script], list[str]]:
    """Remove the condition attributes from ``attrib``; (parsed scripts, problems as 'attr: why')."""
    scripts: dict[str, Script] = {}
    problems: list[str] = []
    for attr in CONDITIONS:
        text = attrib.pop(attr, None)
        if text is None:
            continue
        from canguard.bt.scripting.script import Script  # the language: only for nodes with conditions

        try:
            scripts[attr] = Script(text)
        except ScriptError as exc:
            problems.append(f"{attr}: script {quote(text)}: {exc}")
    return scripts, problems


def _run_post(node: py_trees.behaviour.Behaviour, script: Script | None, board: TreeBlackboard, attr: str) -> bool:
    """Run a post-condition script; False when it failed (its error noted on the node)."""
    if script is None:
        return True
    try:
        run_script(node, attr, script, board)
    except ScriptError:
        return False
    return True


def _precondition(node: py_trees.behaviour.Behaviour, scripts: Mapping[str, Script], board: TreeBlackboard) -> Any:
    """The status BT.CPP's ``checkPreConditions`` substitutes (None: tick the node)."""
    if node.status != RUNNING:
        for attr, status in (("_failureIf", FAILURE), ("_successIf", SUCCESS), ("_skipIf", SKIPPED)):
            script = scripts.get(attr)
            if script is not None and run_script(node, attr, script, board, condition=True):
                return status
    script = scripts.get("_while")
    if script is not None and not run_script(node, "_while", script, board, condition=True):
        return SKIPPED  # while running: halted below (mark_skipped stops it: _onHalted runs)
    return None


def install_conditions(node: py_trees.behaviour.Behaviour, scripts: Mapping[str, Script],
                       board: TreeBlackboard) -> None:
    """Wrap ``node``'s tick and stop (instance attributes) with its conditions, run on ``board``."""
    if not scripts:
        return
    tick, stop = node.tick, node.stop

    def tick_with_conditions() -> Iterator[py_trees.behaviour.Behaviour]:
        try:
            substituted = _precondition(node, scripts, board)
        except ScriptError:  # fail-safe: the node fails (halted first if it was running)
            if node.status == RUNNING:
                stop_with_conditions(INVALID)
            stop(FAILURE)
            yield node
            return
        if substituted is SKIPPED:
            mark_skipped(node)
            yield node
            return
        if substituted is not None:
            stop(substituted)
            yield node
        else:
            yield from tick()
        # as BT.CPP's executeTick: the post-conditions follow a completed status, substituted or ticked
        if getattr(node, "skipped", False) or node.status not in (SUCCESS, FAILURE):
            return
        first = "_onSuccess" if node.status == SUCCESS else "_onFailure"
        if not (_run_post(node, scripts.get(first), board, first)
                and _run_post(node, scripts.get("_post"), board, "_post")):
            node.status = FAILURE  # a post-condition that fails fails the node (BT.CPP throws)

    def stop_with_conditions(new_status: Any = INVALID) -> None:
        was_halted = halted(node, new_status)
        stop(new_status)
        if was_halted:
            _run_post(node, scripts.get("_onHalted"), board, "_onHalted")

    node.tick = tick_with_conditions  # type: ignore[method-assign]
    node.stop = stop_with_conditions  # type: ignore[method-assign]
