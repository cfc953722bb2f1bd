"""One config style: every configuration dataclass documents each field (an attribute
docstring below it), and docs/config-reference.md is what scripts/make_config_docs.py
generates from those docstrings, so it cannot drift from the code."""

from __future__ import annotations

import dataclasses
import re
import runpy
import tomllib
from pathlib import Path

import pytest

from dano._config import field_docs, schema_markdown, typed_table
from dano.errors import DanoError

ROOT = Path(__file__).resolve().parent.parent


def _configs():
    from dano.experiments.grasp import GraspPandaConfig
    from dano.experiments.push import PushPandaConfig, PushSphereConfig
    from dano.nerf import FieldConfig, TrainConfig
    from dano.render import RenderConfig
    from dano.sim import NewtonConfig
    from dano.sysid.config import (ObjectConfig, OptionsConfig, ParameterConfig, SceneConfig, SysIdConfig,
                                   TrajectoryConfig)
    from dano.tracking import TrackConfig
    from dano.trajopt import ILQRConfig

    return [SysIdConfig, SceneConfig, ObjectConfig, TrajectoryConfig, ParameterConfig, OptionsConfig,
            PushSphereConfig, PushPandaConfig, GraspPandaConfig, ILQRConfig, NewtonConfig, RenderConfig, TrainConfig,
            FieldConfig, TrackConfig]


def _script():
    return runpy.run_path(str(ROOT / "scripts" / "make_config_docs.py"), run_name="make_config_docs")


def test_committed_config_reference_is_what_the_script_generates():
    text = (ROOT / "docs" / "config-reference.md").read_text()
    assert text == _script()["render"](), "docs/config-reference.md is out of date: run scripts/make_config_docs.py"


def test_every_config_field_has_a_docstring():
    for cls in _configs():
        missing = [f.name for f in dataclasses.fields(cls) if not field_docs(cls).get(f.name)]
        assert not missing, f"{cls.__name__}: fields without a docstring: {missing}"


def test_config_reference_examples_are_valid_files():
    from dano.experiments.trajopt_run import CONFIGS
    from dano.sysid.config import SysIdConfig

    text = (ROOT / "docs" / "config-reference.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 2
    assert typed_table(tomllib.loads(blocks[0]), SysIdConfig, "").scene.object[0].name == "soap"
    raw = tomllib.loads(blocks[1])
    assert typed_table(raw, CONFIGS[raw["task"]], "").goal_angle == 15.0


def test_schema_markdown_walks_nested_tables_and_refuses_undocumented_fields():
    from dano.sysid.config import SysIdConfig

    md = schema_markdown(SysIdConfig, "sysid")
    for head in ("[scene]", "[[scene.object]]", "[[trajectory]]", "[[parameter]]", "[options]"):
        assert f"### `{head}`" in md
    assert "| dt | number | required |" in md and '| contact_model | string | `"centroid"` |' in md

    @dataclasses.dataclass(frozen=True)
    class Bad:
        documented: int = 1
        """A documented field."""
        undocumented: float = 2.0

    assert field_docs(Bad) == {"documented": "A documented field."}
    with pytest.raises(DanoError, match="Bad.undocumented: no docstring"):
        schema_markdown(Bad, "bad")


def test_configs_check_their_values_when_built():
    from dano.experiments.push import PushSphereConfig
    from dano.nerf import TrainConfig
    from dano.sysid.config import OptionsConfig
    from dano.tracking import TrackConfig
    from dano.trajopt import ILQRConfig, Options

    assert Options is ILQRConfig  # old name, kept
    for make, message in [(lambda: PushSphereConfig(horizon=1), "horizon out of range: 1"),
                          (lambda: OptionsConfig(substeps=0), r"\[options\].substeps: must be at least 1"),
                          (lambda: TrackConfig(poor_iou=2.0), "poor_iou must be in"),
                          (lambda: TrainConfig(minutes=0.0), "--minutes must be a positive number"),
                          (lambda: ILQRConfig(line_search=(2.0,)), "line_search step sizes")]:
        with pytest.raises(DanoError, match=message):
            make()
    with pytest.raises(DanoError, match="horizon out of range"):
        dataclasses.replace(PushSphereConfig(), horizon=0)


def test_an_unbounded_setting_is_written_as_strict_json_and_read_back(tmp_path):
    """config.json files are strict JSON (other tools refuse Python's ``Infinity``): an
    infinite setting is written as the string "inf" and read back as the number."""
    import json

    from dano._config import read_table
    from dano._files import config_json
    from dano.experiments.push import PushObjectConfig

    config = PushObjectConfig(max_force=float("inf"), object="spot.dano")
    path = tmp_path / "config.json"
    path.write_text(config_json(dataclasses.asdict(config)))
    json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    assert typed_table(read_table(path), PushObjectConfig, "") == config
    with pytest.raises(DanoError, match=r"\[max_force\]: expected a number, got the string 'lots'"):
        typed_table({**json.loads(path.read_text()), "max_force": "lots"}, PushObjectConfig, "")
