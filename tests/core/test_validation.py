"""`pirl_sim.validation.list_arg`: the one argparse type of every comma-separated option."""

import argparse

import pytest

from pirl_sim.validation import list_arg


def test_lists_parse_to_tuples_of_their_kind():
    assert list_arg(float, low=0, empty=True)("0, 10,,20") == (0.0, 10.0, 20.0)
    assert list_arg(float, low=0, empty=True)("") == ()
    assert list_arg(int, low=1)("10,20") == (10, 20)
    assert list_arg(int)("-1,0,3") == (-1, 0, 3)
    assert list_arg(str, empty=True)("none, truth") == ("none", "truth")


@pytest.mark.parametrize("parse, text, what", [
    (list_arg(float, low=0), "", "numbers >= 0"),  # empty not allowed
    (list_arg(float, low=0), "1,x", "numbers >= 0"),
    (list_arg(float, low=0), "-0.5", "numbers >= 0"),
    (list_arg(float), "nan", "numbers"),
    (list_arg(float), "inf", "numbers"),
    (list_arg(int, low=1), "0", "integers >= 1"),
    (list_arg(int, low=1), "2.5", "integers >= 1"),
    (list_arg(str), "", "names"),
])
def test_bad_lists_name_the_text_and_what_is_allowed(parse, text, what):
    with pytest.raises(argparse.ArgumentTypeError, match=f"expected comma-separated {what}, got {text!r}"):
        parse(text)


def test_an_option_with_a_bad_list_exits_with_argparses_message(capsys):
    p = argparse.ArgumentParser(prog="x")
    p.add_argument("--knn-k", type=list_arg(int, low=1), default="10")
    assert p.parse_args([]).knn_k == (10,)
    with pytest.raises(SystemExit):
        p.parse_args(["--knn-k", "0,5"])
    assert "--knn-k" in capsys.readouterr().err
    with pytest.raises(TypeError, match="kind must be int, float or str"):
        list_arg(bool)
