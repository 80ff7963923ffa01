"""The scripting language behaves as BehaviorTree.CPP 4's (behaviour ported from its
tests/script_parser_test.cpp: ParserTest.*), on a plain dict-backed blackboard."""

from __future__ import annotations

import math

import pytest

from canguard.bt.scripting import ScriptError
from canguard.bt.scripting.script import Script


class Board:
    """The smallest blackboard a script accepts: a dict, plus declared-but-empty entries."""

    def __init__(self, **values: object) -> None:
        self.values: dict[str, object] = dict(values)
        self.types: dict[str, type] = {}

    def has(self, key: str) -> bool:
        return key in self.values or key in self.types

    def get(self, key: str) -> object:
        return self.values[key]

    def set(self, key: str, value: object) -> None:
        self.values[key] = value

    def declared_type(self, key: str) -> type | None:
        return self.types.get(key)


def run(text: str, bb: Board | None = None) -> object:
    return Script(text).run(bb if bb is not None else Board())


def error(text: str, bb: Board | None = None) -> ScriptError:
    with pytest.raises(ScriptError) as info:
        run(text, bb)
    return info.value


# ParserTest.AnyTypes: literals and their types
@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("628", 628),
        ("0x100", 256),
        ("0X100", 256),
        ("3.14", 3.14),
        ("3.14e2", 314.0),
        ("3.14e-2", 0.0314),
        ("3e2", 300.0),
        ("3e-2", 0.03),
        ("'hello world '", "hello world "),
        ("true", 1.0),  # BT.CPP 4: the boolean literals are reals
        ("false", 0.0),
        ("-628", -628.0),
        ("-3.14", -3.14),
    ],
)
def test_literals(text: str, value: object) -> None:
    result = run(text)
    assert result == value
    assert type(result) is type(value)


# ParserTest.AnyTypes_Failing + TokenizerEdgeCases: malformed tokens fail at parse, with their column
@pytest.mark.parametrize(
    ("text", "column", "words"),
    [
        ("0X100g", 1, "hexadecimal"),
        ("0X100.", 1, "hexadecimal"),
        ("3foo", 1, "followed by letters"),
        ("65.", 1, "digits after the decimal point"),
        ("65.43foo", 1, "followed by letters"),
        ("x := 'hello", 6, "unterminated string"),
        ("0x", 1, "hexadecimal digits"),
        ("0xG", 1, "hexadecimal digits"),
        ("3e", 1, "exponent"),
        ("3e+", 1, "exponent"),
        ("a := 1 $ 2", 8, "unexpected character '$'"),
    ],
)
def test_malformed_tokens_name_their_column(text: str, column: int, words: str) -> None:
    with pytest.raises(ScriptError) as info:
        Script(text)
    assert words in str(info.value)
    assert str(info.value).startswith(f"column {column}: ")


@pytest.mark.parametrize("text", ["", "   ", "\t\n\r", ";;"])
def test_empty_script_is_a_parse_error(text: str) -> None:
    with pytest.raises(ScriptError, match="empty script"):
        Script(text)


def test_unknown_variable_fails_when_run_not_at_parse() -> None:
    Script("foo + 1")  # parses: the entry is looked up when the script runs
    err = error("foo + 1")
    assert str(err).startswith("column 1: variable not found: [foo]")


# ParserTest.Equations
def test_equations_assignment_operators_and_types() -> None:
    bb = Board()
    assert run("x:= 3; y:=5; x+y", bb) == 8.0
    assert bb.values == {"x": 3, "y": 5}
    assert run("x+=1", bb) == 4 and bb.values["x"] == 4
    assert run("x += 1", bb) == 5
    assert run("x-=1", bb) == 4
    assert run("x -= 1", bb) == 3
    assert run("x*=2", bb) == 6
    assert run("-x", bb) == -6.0
    assert run("x/=2", bb) == 3 and bb.values["x"] == 3
    assert type(bb.values["x"]) is int  # the entry keeps its integer type
    assert run("y", bb) == 5
    assert run("y/2", bb) == 2.5
    assert run("y*2", bb) == 10.0
    assert run("y-x", bb) == 2.0
    assert run("y & x", bb) == 5 & 3
    assert run("y | x", bb) == 5 | 3
    assert run("y ^ x", bb) == 5 ^ 3
    assert "expects integers" in str(error("y ^ 5.1", bb))

    assert run("A:='hello'; B:=' '; C:='world'; A+B+C", bb) == "hello world"
    assert run("A= '   right'; B= ' center '; C= 'left    '  ", bb) == "left    "
    assert (bb.values["A"], bb.values["B"], bb.values["C"]) == ("   right", " center ", "left    ")
    assert len(bb.values) == 5

    # an entry keeps its type once created
    assert "can't assign the string '   right' to the entry [x], which holds an integer" in str(error("x=A", bb))
    assert "can't assign the string 'msg'" in str(error("x='msg'", bb))
    assert "can't assign the real 1.0 to the entry [A], which holds a string" in str(error("A=1.0", bb))
    # the left side of an assignment must be an entry: refused at parse time
    for text in (" 'hello' = 'world' ", " 'hello' = 2.0 ", " 3.0 = 2.0 "):
        with pytest.raises(ScriptError, match="must be the name of a blackboard entry"):
            Script(text)
    # '=' does not create an entry
    err = error("new_var=69", bb)
    assert "[new_var] doesn't exist yet" in str(err) and "[:=]" in str(err)
    assert "new_var" not in bb.values

    assert run("x < y", bb) == 1.0
    assert run("y > x", bb) == 1.0
    assert run("y != x", bb) == 1.0
    assert run("y == x", bb) == 0.0
    assert run(" 'hello' == 'hello'", bb) == 1.0
    assert run(" 'hello' != 'world'", bb) == 1.0
    assert run(" 'hello' < 'world'", bb) == 1.0
    assert run(" 'hello' > 'world'", bb) == 0.0
    assert run("y == x ? 'T' : 'F'", bb) == "F"
    assert run("y != x ? 'T' : 'F'", bb) == "T"
    assert run("y == 5", bb) == 1.0 and run("x == 3", bb) == 1.0
    assert run(" 'true' ", bb) == "true"

    run("v1:= true; v2:= false", bb)
    assert bb.values == {**bb.values, "v1": 1.0, "v2": 0.0} and type(bb.values["v1"]) is float
    assert run(" v2 = true ", bb) == 1.0
    assert run(" v2 = !false ", bb) == 1.0
    assert run(" v2 = !v2 ", bb) == 0.0
    assert run("v1 && v2", bb) == 0.0
    assert run("v1 || v2", bb) == 1.0
    assert run("(y == x) && (x == 3)", bb) == 0.0
    assert run("(y == x) || (x == 3)", bb) == 1.0
    assert run(" y == x  &&  x == 3 ", bb) == 0.0
    assert run(" y == x  ||  x == 3 ", bb) == 1.0
    # a string compared with a number is read as a number
    assert run(" par1:='3'; par2:=3; par1==par2", bb) == 1.0
    assert run(" par1:='3'; par2:=4; par1!=par2", bb) == 1.0


def test_real_into_integer_entry_is_an_error_and_leaves_it_unchanged() -> None:
    bb = Board(count=3)
    err = error("count = 2.5", bb)
    assert "can't assign the real 2.5 to the entry [count], which holds an integer" in str(err)
    assert str(err).startswith("column 7: ")
    assert "can't assign the real 1.5 to the entry [count]" in str(error("count /= 2", bb))
    assert bb.values["count"] == 3
    assert run("count = 4.0", bb) == 4 and type(bb.values["count"]) is int
    assert run("count = '7'", bb) == 7  # a string holding a number
    # a real entry takes integers
    bb.values["speed"] = 1.5
    assert run("speed = 2", bb) == 2.0 and type(bb.values["speed"]) is float


def test_declared_type_applies_to_a_string_into_an_empty_entry() -> None:
    """BT.CPP: an entry a port declared (no value yet) takes a number as it is, and parses a string to its type."""
    bb = Board()
    bb.types["limit"] = int
    assert "which is declared as an integer" in str(error("limit = 'half'", bb))
    assert run("limit = '16'", bb) == 16 and type(bb.values["limit"]) is int
    bb.types["ratio"] = int
    assert run("ratio = 0.5", bb) == 0.5  # Any::copyInto into an empty entry copies the value as it is
    bb.types["flag"] = bool
    assert "expected true, false, 0 or 1" in str(error("flag = '2'", bb))
    assert run("flag = 'true'", bb) is True


# ParserTest.NotInitializedComparison
@pytest.mark.parametrize("text", ["x < 0", "x == 0", "x > 0", "x + 1", "x += 1", "y := x", "-x"])
def test_entry_without_value(text: str) -> None:
    bb = Board()
    bb.types["x"] = int
    assert "is not initialized" in str(error(text, bb))


def test_a_name_without_an_entry_is_not_found() -> None:
    """No enums are registered (BT.CPP registers them from C++ only): an unknown name is an error."""
    assert "variable not found: [RED]" in str(error("A := RED", Board()))


# ParserTest.OperatorAssociativity_Issue1029
@pytest.mark.parametrize(
    ("text", "value"),
    [("5 - 2 + 1", 4.0), ("10 - 3 - 2", 5.0), ("2 + 3 - 1", 4.0), ("12 / 3 / 2", 2.0), ("12 / 3 * 2", 8.0),
     ("2 + 3 * 4 - 1", 13.0)],
)
def test_left_associativity(text: str, value: float) -> None:
    assert run(text) == value


def test_string_concatenation() -> None:
    bb = Board()
    assert run("A:='hello'; B:=' world'; A .. B", bb) == "hello world"
    assert run("A .. ' ' .. B", bb) == "hello  world"
    assert run("A:='65'; B:='66'; A..B", bb) == "6566"  # TokenizerEdgeCases: '..' after digits
    assert run("'n=' .. 3") == "n=3"
    assert run("'v=' .. 1.5") == "v=1.500000"  # reals as C's std::to_string prints them
    assert run("2 .. 'x'") == "2x"
    assert "operation not permitted" in str(error("1 .. 2"))
    assert "operation not permitted" in str(error("'a' - 'b'"))
    assert run("s := 'ab'; s += 'cd'", bb) == "abcd"
    assert "not supported for strings" in str(error("s := 'ab'; s -= 'cd'"))


# ParserTest.CompareWithNegativeNumber_Issue832
def test_compare_with_negative_number() -> None:
    assert run("A:=0; A!=-1") == 1.0
    assert run("A:=-1; A!=-1") == 0.0
    assert run("A:=0; A==-1") == 0.0
    assert run("A:=0; A>-1") == 1.0
    assert run("A:=0; A<-1") == 0.0


# ParserTest.ChainedComparisons
@pytest.mark.parametrize(
    ("text", "value"),
    [("1 < 2 < 3", True), ("3 > 2 > 1", True), ("1 < 2 > 3", False), ("5 == 5 == 5", True),
     ("5 == 5 != 3", True), ("1 <= 2 <= 3", True), ("3 >= 2 >= 1", True), ("3 < 2 < 5", False)],
)
def test_chained_comparisons(text: str, value: bool) -> None:
    result = run(text)
    assert result == float(value) and type(result) is float  # BT.CPP: a comparison is the real 1.0 or 0.0


# ParserTest.OperatorPrecedence
@pytest.mark.parametrize(
    ("text", "value"),
    [("6 | 3 & 5", 7), ("true && (6 | 0)", True), ("false || true && true", True),
     ("false && true || true", True), ("(2 + 3) * 4", 20.0), ("2 * (3 + 4)", 14.0), ("6 & 3 == 2", True),
     ("1 + 2 == 3 && 'a' < 'b'", True), ("-2 * 3", -6.0), ("!false == true", True)],
)
def test_operator_precedence(text: str, value: object) -> None:
    assert run(text) == value


def test_logic_results_are_reals_and_concatenate_as_reals() -> None:
    """BT.CPP 4: true, false, comparisons and logic operators are the reals 1.0 / 0.0, so `..` prints them with %f."""
    assert run("'t' .. true") == "t1.000000"
    assert run("'f' .. (1 > 2)") == "f0.000000"
    assert run("'n' .. !false .. (true && true)") == "n1.0000001.000000"
    assert all(type(run(text)) is float for text in ("true", "1 < 2", "!0", "1 || 0"))


# ParserTest.UnaryOperators
def test_unary_operators() -> None:
    assert run("!true") == 0.0
    assert run("!false") == 1.0
    assert run("!!true") == 1.0
    assert run("~0") == -1
    assert run("~0x0F & 0xFF") == 0xF0
    assert run("-(3 + 2)") == -5.0
    assert run("10 + -3") == 7.0
    assert "expects a number" in str(error("-'a'"))


# ParserTest.TernaryExpressions
@pytest.mark.parametrize(
    ("text", "value"),
    [("true ? 1 : 2", 1), ("false ? 1 : 2", 2), ("true ? 2 + 3 : 10", 5.0), ("false ? 10 : 2 + 3", 5.0),
     ("3 > 2 ? 'yes' : 'no'", "yes"), ("3 < 2 ? 'yes' : 'no'", "no"), ("false ? 1 : true ? 2 : 3", 2),
     ("x := 2 > 1 ? 'big' : 'small'; x", "big")],
)
def test_ternary(text: str, value: object) -> None:
    assert run(text) == value


def test_ternary_evaluates_only_the_chosen_branch() -> None:
    bb = Board()
    assert run("true ? (a := 1) : (b := 2)", bb) == 1
    assert bb.values == {"a": 1}


# ParserTest.MultipleStatements
def test_multiple_statements() -> None:
    bb = Board()
    run("a:=1;;; b:=2;;", bb)
    assert bb.values == {"a": 1, "b": 2}
    assert run("a:=10; b:=20; a+b", bb) == 30.0
    assert run("A:=5;\nB:=6", bb) == 6  # ParserTest.NewLine


def test_logic_operators_typing() -> None:
    assert run("1 && 0") == 0.0
    assert run("2.5 && 1") == 1.0  # a real is true when not zero
    assert "expects booleans" in str(error("2 && 1"))  # an integer must be 0 or 1
    assert "expected booleans" in str(error("'a' || true"))
    # both sides are evaluated (BT.CPP has no short-circuit)
    assert "variable not found: [missing]" in str(error("false && missing"))


def test_division_by_zero_gives_ieee_values() -> None:
    assert run("1 / 0") == math.inf
    assert run("-1 / 0") == -math.inf
    assert math.isnan(run("0 / 0"))  # type: ignore[arg-type]
    bb = Board(n=4)
    assert "can't assign the real inf to the entry [n]" in str(error("n /= 0", bb))
    assert bb.values["n"] == 4


def test_comparison_of_mixed_types() -> None:
    assert run("'true' == 1") == 1.0
    assert "can't compare the string 'abc' with a number" in str(error("'abc' < 1"))
    bb = Board(obj=object())
    assert "can't mix different types" in str(error("obj == 1", bb))
    assert run("0.1 + 0.2 == 0.3") == 1.0  # reals equal within float epsilon, as BT.CPP


@pytest.mark.parametrize(
    ("text", "column", "words"),
    [
        ("(2 + 3", 7, "expected ')' to close the '(' at column 1, got the end of the script"),
        ("x := 1 ? 2", 11, "expected ':' of the [?] at column 8"),
        ("x := * 3", 6, "expected a value"),
        ("x := 1 )", 8, "expected an operator, ';' or the end of the script, got ')'"),
        ("a + b := 1", 3, "left side of [:=] must be the name of a blackboard entry"),
        ("1 + 99999999999999999999", 5, "does not fit in 64 bits"),
    ],
)
def test_syntax_errors_name_position_and_what_was_expected(text: str, column: int, words: str) -> None:
    with pytest.raises(ScriptError) as info:
        Script(text)
    assert isinstance(info.value, ValueError)
    assert str(info.value).startswith(f"column {column}: ") and info.value.pos == column - 1
    assert words in str(info.value)


def test_error_in_a_multiline_script_names_line_and_column() -> None:
    with pytest.raises(ScriptError) as info:
        Script("a := 1;\nb := (2 *\n  )")
    assert str(info.value).startswith("line 3, column 3: expected a value")
    err = error("a := 1;\nb = 2")
    assert str(err).startswith("line 2, column 3: ")


def test_large_invalid_script_is_a_clean_error() -> None:
    # ParserTest.ValidateScriptLargeError_Issue923: no crash, a ScriptError
    chunk = "+6e66>6666.6+66\r6>6;6e62=6+6e66>66666'; en';o';o'; en'; \x7fn\x7fr;6.6+66.H>6+6\x806\x1e;@e66"
    with pytest.raises(ScriptError):
        Script(chunk * 10)
    with pytest.raises(ScriptError, match="nested too deeply"):
        Script("(" * 500 + "1" + ")" * 500)
    with pytest.raises(ScriptError, match="nested too deeply"):
        Script("+".join(["1"] * 1000))
    assert run("+".join(["1"] * 100)) == 100.0


def test_parse_once_run_many_times() -> None:
    script = Script("count := count + 1; total += step; count >= 3")
    bb = Board(count=0, total=0.0, step=0.5)
    assert [script.condition(bb) for _ in range(4)] == [False, False, True, True]
    assert bb.values == {"count": 4, "total": 2.0, "step": 0.5}


def test_condition_needs_a_boolean_convertible_result() -> None:
    assert Script("1").condition(Board()) is True
    assert Script("0.0").condition(Board()) is False
    with pytest.raises(ScriptError, match="expected a boolean result"):
        Script("2").condition(Board())
    with pytest.raises(ScriptError, match="expected a boolean result"):
        Script("'yes'").condition(Board())


def test_root_blackboard_names_and_assignment_value() -> None:
    bb = Board()
    assert run("@armed := true; @armed", bb) == 1.0
    assert bb.values == {"@armed": 1.0}
    assert run("a := b := 2", bb) == 2 and bb.values["a"] == bb.values["b"] == 2
