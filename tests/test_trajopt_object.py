"""``dano trajopt push``, the push task for any object: its bad input. The task itself runs
in the own-object walkthrough (tests/test_own_object_doc.py: a 0.2 m toy pushed to a goal)."""

import pytest

from dano.cli import main


@pytest.mark.parametrize("args, message", [
    (["push", "--goal", "0.3"], "--goal must be two numbers X,Y"),
    (["push", "--goal", "a,b"], "--goal must be two numbers X,Y"),
    (["push", "--goal", "0,0"], "is where the object starts"),
    (["push", "--object", "missing.dano"], "missing.dano"),
    (["push", "--pusher", "panda"], "pusher out of range"),
    (["push-sphere", "--object", "builtin:bunny"], "push-sphere does not use --object"),
])
def test_push_bad_input(args, message, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["trajopt", *args, "-o", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and not out.exists()
