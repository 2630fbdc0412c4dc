import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from conftest import CONFIGS
from fracture.pipeline.config import dump_config, load_config, parse_override
from fracture.errors import ConfigError

EXPERIMENTS = sorted(CONFIGS.glob("*.yaml"))
GROUPS = sorted(p for p in CONFIGS.glob("*/*.yaml"))


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def test_there_are_experiments_and_groups():
    assert any(p.name == "example.yaml" for p in EXPERIMENTS)
    assert GROUPS


@pytest.mark.parametrize("path", EXPERIMENTS, ids=lambda p: p.name)
def test_every_experiment_loads(path):
    cfg = load_config(path)
    assert cfg.name == path.stem
    for key in ("exterior", "fracture"):
        if getattr(cfg.input, key) is not None:
            assert Path(getattr(cfg.input, key)).is_absolute() and Path(getattr(cfg.input, key)).is_file()


@pytest.mark.parametrize("group", GROUPS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_group_validates_on_the_defaults(tmp_path, group):
    cfg = load_config(write(tmp_path / "x.yaml", f"defaults: [{group.with_suffix('')}]\n"))
    assert cfg.name == "x"


def test_defaults_fill_everything_and_experiment_overrides(tmp_path, slab_meshes):
    write(tmp_path / "base.yaml", "grid: {resolution: 30, padding: 0.1}\npsi: {stress_weight: 2.0}\n")
    cfg = load_config(write(tmp_path / "exp.yaml", """\
        defaults: [base]
        grid: {resolution: [10, 11, 12]}
        input: {exterior: slab.obj}
        """))
    assert cfg.tree()["grid"] == {"resolution": [10, 11, 12], "padding": 0.1, "min_across": 8, "max_memory_gb": 8.0}
    assert cfg.psi.stress_weight == 2.0 and cfg.psi.strength_weight == 1.0
    assert cfg.pyramid.levels == 5
    assert cfg.input.exterior == str(slab_meshes[0].resolve())
    assert cfg.strength.layers[0].kind == "marble"
    assert "grain_frequency" in cfg.tree()["strength"]["layers"][0]  # layer defaults filled in


def test_resolved_config_round_trips(tmp_path, small_config):
    cfg = load_config(small_config)
    again = load_config(write(tmp_path / "resolved.yaml", dump_config(cfg)))
    assert again.tree() == {**cfg.tree(), "name": "small"}


def test_paths_are_relative_to_the_file_that_sets_them(tmp_path, slab_meshes):
    sub = tmp_path / "group"
    sub.mkdir()
    (sub / "mesh.obj").write_text(slab_meshes[0].read_text())
    write(sub / "input.yaml", "input: {exterior: mesh.obj}\n")
    cfg = load_config(write(tmp_path / "exp.yaml", "defaults: [group/input]\n"))
    assert cfg.input.exterior == str((sub / "mesh.obj").resolve())


def _error(tmp_path, text, overrides=()):
    path = write(tmp_path / "bad.yaml", text)
    with pytest.raises(ConfigError) as err:
        load_config(path, overrides)
    return str(err.value), path


@pytest.mark.parametrize("text, key, words", [
    ("grdi: {resolution: 5}\n", "grdi", "unknown key"),
    ("grid: {resolutoin: 5}\n", "grid.resolutoin", "unknown key; expected one of: max_memory_gb, min_across, padding, resolution"),
    ("grid: {resolution: fifty}\n", "grid.resolution", "got 'fifty' (str), expected an integer or a list of 3 integers"),
    ("grid: {resolution: [10, 10]}\n", "grid.resolution", "expected an integer or a list of 3 integers"),
    ("grid: {resolution: 2}\n", "grid.resolution", "in [4, 1024]"),
    ("pyramid: {levels: 12}\n", "pyramid.levels", "got 12 (int), expected an integer in [1, 8]"),
    ("pyramid: {levels: 4.5}\n", "pyramid.levels", "expected an integer"),
    ("psi: {stress_weight: -1}\n", "psi.stress_weight", "expected a number in [0, 100]"),
    ("seed: -1\n", "seed", "expected an integer in [0, 4294967295]"),
    ("psi: {stress_weight: .nan}\n", "psi.stress_weight", "expected a number"),
    ("strength: {normalize: 1}\n", "strength.normalize", "expected true or false"),
    ("preview: {axis: w}\n", "preview.axis", "expected one of 'x', 'y', 'z'"),
    ("strength: {layers: []}\n", "strength.layers", "expected a list of at least 1"),
    ("strength: {layers: [{kind: granite}]}\n", "strength.layers[0].kind", "expected one of 'marble'"),
    ("strength: {layers: [{weight: 1}]}\n", "strength.layers[0]", "with a 'kind' key"),
    ("strength: {layers: [{kind: bricks, brick_size: 1}]}\n", "strength.layers[0].brick_size", "unknown key"),
    ("strength: {layers: [{kind: radial, axis: w}]}\n", "strength.layers[0].axis", "one of 'x', 'y', 'z'"),
    ("input: {exterior: nowhere.obj}\n", "input.exterior", "file not found: 'nowhere.obj'"),
    ("input: {exterior: .}\n", "input.exterior", "a directory, expected a file: '.'"),
    ("input: 3\n", "input", "expected a mapping"),
    ("name: ../../elsewhere\n", "name", "is not a plain name"),
    ("name: /tmp/elsewhere\n", "name", "is not a plain name"),
    ("refine: {search: fast}\n", "refine.search", "got 'fast' (str), expected one of 'graphcut', 'none'"),
    ("refine: {band: 0}\n", "refine.band", "expected a number in [1, 200]"),
    ("refine: {core: .nan}\n", "refine.core", "expected a number"),
    # rules between the keys of one layer
    ("strength: {layers: [{kind: bricks, length_axis: z, height_axis: z}]}\n", "strength.layers[0].height_axis",
     "got 'z' (str), expected an axis other than length_axis ('z')"),
    ("strength: {layers: [{kind: marble, vein_direction: [0, 0, 0]}]}\n", "strength.layers[0].vein_direction",
     "expected a direction of non-zero length"),
    ("strength: {layers: [{kind: grain, fibres: along, path: d.npy}]}\n", "strength.layers[0].path",
     "expected null: only fibres: volume reads path (these fibres are 'along')"),
    ("strength: {layers: [{kind: grain, fibres: volume, center: [0, 0, 0]}]}\n", "strength.layers[0].center",
     "only fibres: around reads center"),
    ("strength: {layers: [{kind: grain, fibres: around, bounds: [[0, 0, 0], [1, 1, 1]]}]}\n",
     "strength.layers[0].bounds", "only fibres: volume reads bounds"),
])
def test_config_errors_name_file_key_given_and_expected(tmp_path, text, key, words):
    message, path = _error(tmp_path, text)
    assert message.startswith(f"{path}: {key}: "), message
    assert words in message


def test_errors_name_the_group_file_that_set_the_value(tmp_path):
    group = write(tmp_path / "group.yaml", "pyramid: {sigma: 0}\n")
    message, _ = _error(tmp_path, "defaults: [group]\n")
    assert message.startswith(f"{group}: pyramid.sigma: got 0")


def test_yaml_problems(tmp_path):
    message, path = _error(tmp_path, "grid: {resolution: [1, 2\n")
    assert message.startswith(f"{path}:2: invalid YAML")
    message, _ = _error(tmp_path, "- a\n- b\n")
    assert "expected a mapping" in message
    # Safe loading: no Python objects are constructed from tags.
    message, _ = _error(tmp_path, "name: !!python/object/apply:os.system ['echo hi']\n")
    assert "invalid YAML" in message
    message, _ = _error(tmp_path, "grid:\n  resolution: 20\nseed: 1\ngrid:\n  resolution: 30\n")
    assert message.startswith(f"{path}:4: invalid YAML: key 'grid' given twice (first on line 1)"), message
    message, _ = _error(tmp_path, "grid: {resolution: 20, resolution: 30}\n")
    assert "key 'resolution' given twice" in message
    # aliases of aliases (a few lines standing for a billion values) are refused before they are expanded
    bomb = "a0: &a0 [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 9)}]\n" for k in range(1, 10))
    message, path = _error(tmp_path, bomb)
    assert message == f"{path}:1: invalid YAML: its aliases expand to more than 1,000,000 values; expected a config"
    anchored = "seed: &n 12\ngrid: {resolution: *n}\n"  # an alias or two is fine
    assert load_config(write(tmp_path / "ok.yaml", anchored)).grid.resolution == 12
    message, _ = _error(tmp_path, "defaults: [missing]\n")
    assert "included config 'missing' not found" in message
    write(tmp_path / "a.yaml", "defaults: [b]\n")
    write(tmp_path / "b.yaml", "defaults: [a]\n")
    with pytest.raises(ConfigError, match="cycle of defaults"):
        load_config(tmp_path / "a.yaml")
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="is a directory; expected a YAML config file"):
        load_config(tmp_path)
    for empty in ("", "# nothing yet\n"):  # read as all defaults, the run would fail far from the file
        with pytest.raises(ConfigError) as error:
            load_config(write(tmp_path / "empty.yaml", empty))
        assert str(error.value).startswith(f"{tmp_path / 'empty.yaml'}: holds no settings (the file is empty or "
                                           "only comments)")


def test_yaml_that_is_legal_but_no_config_is_said_in_one_line(tmp_path):
    message, path = _error(tmp_path, "? [a, b]\n: 1\n")  # a complex key
    assert message == f"{path}:1: invalid YAML: a key is a list; expected a name"
    message, path = _error(tmp_path, "seed: " + "[" * 5000 + "]" * 5000 + "\n")  # PyYAML's parser recurses
    assert message == f"{path}: nests values too deeply to be read; expected a config"
    message, path = _error(tmp_path, "name: &x [*x]\n")  # a value that holds itself
    assert message.startswith(f"{path}:1: invalid YAML: a value holds itself through an alias")
    message, path = _error(tmp_path, "defaults: [/]\n")
    assert message.startswith(f"{path}: defaults: got '/', expected the path of a config file or a preset's name")
    # a merge key is YAML, and a key it brings may be given again beside it (not twice by hand)
    merged = "strength:\n  layers:\n    - &base {kind: marble, weight: 0.5}\n    - {<<: *base, weight: 0.25}\n"
    cfg = load_config(write(tmp_path / "merged.yaml", merged))
    assert [(layer.kind, layer.weight) for layer in cfg.strength.layers] == [("marble", 0.5), ("marble", 0.25)]
    message, _ = _error(tmp_path, merged.replace("weight: 0.25}", "weight: 0.25, weight: 0.3}"))
    assert "key 'weight' given twice" in message


def test_an_error_in_a_section_a_file_filled_in_part_names_the_file(tmp_path, small_config):
    message, path = _error(tmp_path, "sweep:\n  grid:\n    seed: []\n")
    assert message.startswith(f"{path}: sweep.grid: got "), message
    message, path = _error(tmp_path, "psi: {1: 2}\n")
    assert message.startswith(f"{path}: psi[1]: unknown key"), message
    message, _ = _error(tmp_path, "seed: 1\n", ["strength.layers[0]=null"])
    assert message.startswith("--set strength.layers[0]=null: strength.layers[0]: got null"), message


def test_a_preset_name_is_the_whole_name(tmp_path):
    """``strength/bricks.old`` is not the preset ``strength/bricks`` (a suffix taken for an extension)."""
    message, _ = _error(tmp_path, "defaults: [strength/bricks.old]\n")
    assert "included config 'strength/bricks.old' not found" in message
    assert load_config(write(tmp_path / "ok.yaml", "defaults: [strength/bricks]\n")).strength.layers


def test_set_overrides(tmp_path, small_config):
    cfg = load_config(small_config, ["psi.stress_weight=3", "grid.resolution=[8, 9, 10]",
                                     "strength.layers[0].grain_frequency=2.5", "name=other"])
    assert cfg.psi.stress_weight == 3.0
    assert cfg.grid.resolution == [8, 9, 10]
    assert cfg.strength.layers[0].grain_frequency == 2.5
    assert cfg.name == "other"
    assert load_config(small_config, ["psi.stress_weight = 3"]).psi.stress_weight == 3.0  # spaced as in YAML
    for bad, words in [("psi.stress_weight", "expected key.path=value"),
                       ("psi.stress_weight=-2", "--set psi.stress_weight=-2: psi.stress_weight: got -2"),
                       ("psi.typo=1", "psi.typo: unknown key"),
                       ("typo.key=1", "--set typo.key=1: typo: unknown key"),
                       ("psi.typo.key=1", "--set psi.typo.key=1: psi.typo: unknown key"),
                       ("strength.layers[3].weight=1", "no such list item"),
                       ("strength.layers.0.weight=1", "strength.layers is a list; name an item of it by its index in "
                                                      "brackets, e.g. strength.layers[0]"),
                       ("psi.stress_weight.x=1", "psi.stress_weight is a value (0.4), not a mapping: it has no key 'x'"),
                       ("a..b=1", "expected key.path=value")]:
        with pytest.raises(ConfigError) as err:
            load_config(small_config, [bad])
        assert words in str(err.value), str(err.value)


def test_numbers_in_scientific_notation_are_numbers_in_files_overrides_and_sweeps(tmp_path, small_config):
    from fracture.pipeline.sweep import parse_grid

    assert parse_override("psi.stress_weight=1e-3")[1] == 0.001
    assert parse_override("psi.stress_weight=-2E+1")[1] == -20.0
    assert parse_override("name=1e5x")[1] == "1e5x"  # words that only start like a number stay words
    assert parse_grid(["psi.stress_weight=1e-3,2e-2"]) == {"psi.stress_weight": [0.001, 0.02]}
    text = small_config.read_text() + "\npsi: {stress_weight: 5e-1}\n"
    assert load_config(write(tmp_path / "sci.yaml", text)).psi.stress_weight == 0.5
    assert yaml.safe_load("a: 1e-3")["a"] == "1e-3"  # PyYAML's own loader as it was: nothing changed globally


def test_parse_override_tokens():
    assert parse_override("strength.layers[1].axis=z") == (["strength", "layers", 1, "axis"], "z")
    assert parse_override("grid.resolution=[1, 2, 3]")[1] == [1, 2, 3]
    # words that are not YAML (a star starts an alias) are taken as they are; a broken list is refused
    assert parse_override("input.glob=*.ply") == (["input", "glob"], "*.ply")
    with pytest.raises(ConfigError, match="cannot parse the value"):
        parse_override("grid.resolution=[1, 2")


def test_dumped_config_is_plain_yaml(small_config):
    text = dump_config(load_config(small_config))
    assert "!!" not in text
    assert yaml.safe_load(text)["seed"] == 7


def test_explain_says_what_a_key_means_from_the_same_declarations_the_code_uses():
    """``fracref config --explain``: a key's default, range and description, a section's keys; the
    refine section is the refinement's own parameter type (its defaults are RefineParams')."""
    from fracture.pipeline.config import explain
    from fracture.pipeline.schema import RefineSection
    from fracture.refine.params import RefineParams

    assert explain("strength.layers.volume.path").startswith("strength.layers.volume.path (required): a file path")

    assert explain("refine.step") == ("refine.step = 0.5: a number in [0.0001, 10]. Nominal move per iteration "
                                      "(grid cells) where grad psi has its root mean square")
    assert explain("strength.layers.bricks.mortar").startswith("strength.layers.bricks.mortar = 0.01: a number in [0, 1]")
    assert explain("strength.layers.radial.center").startswith(
        "strength.layers.radial.center = None: a list of 3 numbers (or null)")
    lines = explain("refine").splitlines()
    assert [line.split(" = ")[0] for line in lines] == [f"refine.{k}" for k in RefineSection.model_fields]
    assert list(RefineSection.model_fields) == [*RefineParams.model_fields, "snapshots", "draw"]
    assert RefineSection().params() == RefineParams()
    assert [line.split(" = ")[0] for line in explain("strength.layers.grain").splitlines()] == [
        "strength.layers.grain.weight", "strength.layers.grain.fibres", "strength.layers.grain.axis",
        "strength.layers.grain.center", "strength.layers.grain.ratio", "strength.layers.grain.path",
        "strength.layers.grain.bounds"]
    with pytest.raises(ConfigError, match="unknown key 'stpe' after refine; expected one of iterations"):
        explain("refine.stpe")
    with pytest.raises(ConfigError, match="unknown key 'granite' after strength.layers; expected one of marble"):
        explain("strength.layers.granite")
    out = subprocess.run([sys.executable, "-m", "fracref", "config", "--explain", "psi.stress_weight"],
                         capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("psi.stress_weight = 0.4: a number in [0, 100]")
    bad = subprocess.run([sys.executable, "-m", "fracref", "config", "--explain", "psi.stres"], capture_output=True,
                         text=True)
    assert bad.returncode != 0 and "unknown key 'stres' after psi" in bad.stderr and "Traceback" not in bad.stderr


def test_every_key_of_the_refine_section_reaches_the_refinement():
    """No key of the config's refine section is dropped on the way to the code: every one but the
    pipeline's own (snapshots) is a RefineParams field, and a key RefineParams lacks is an error."""
    import pydantic

    from fracture.refine.params import RefineParams

    cfg = load_config(CONFIGS / "example.yaml", ["refine.step=0.31", "refine.hold=5"])
    params = cfg.refine.params()
    assert type(params) is RefineParams and (params.step, params.hold) == (0.31, 5)
    with pytest.raises(pydantic.ValidationError, match="not_a_parameter"):
        RefineParams(not_a_parameter=1)


def test_the_typed_config_is_one_model_per_section_with_the_values_and_descriptions():
    """Config: one frozen pydantic model per section; each field holds the value the YAML tree has and
    describes itself (what --explain and the viewer's tooltips say)."""
    import pydantic

    from fracture.pipeline.config import explain
    from fracture.pipeline.schema import Config, Section

    cfg = load_config(CONFIGS / "wall.yaml", ["psi.stress_weight=0.7", "view.cameras.material.fov=40"])
    tree = cfg.tree()

    def walk(node, values, where):
        for key in type(node).model_fields:
            value = getattr(node, key)
            if isinstance(value, Section) and not key.isdigit():
                walk(value, values[key], where + key + ".")
            elif key != "layers":
                assert value == values[key], where + key
                if where:
                    assert type(node).model_fields[key].description[1:] in explain(where + key), where + key
        assert set(type(node).model_fields) == set(values)

    walk(cfg, tree, "")
    assert (cfg.psi.stress_weight, cfg.view.cameras.material.fov) == (0.7, 40.0)
    with pytest.raises(pydantic.ValidationError, match="frozen"):
        cfg.psi.stress_weight = 1.0
    assert Config().psi.stress_weight == 0.4


def test_strength_layers_are_typed_by_their_kind_and_give_the_same_field():
    """strength.layers is a list of the kinds' models (a union chosen by kind); the field of typed
    layers is the field of the mappings the config file gives."""
    import numpy as np

    from fields.errors import InputError
    from fields.strength import LAYER_TYPES, as_layer, strength_field

    cfg = load_config(CONFIGS / "wall.yaml")
    layers = cfg.strength.layers
    tree = cfg.tree()["strength"]["layers"]
    assert [type(layer) for layer in layers] == [LAYER_TYPES[layer["kind"]] for layer in tree]
    assert layers[0].mortar == tree[0]["mortar"]
    X = np.random.default_rng(0).random((500, 3))
    bounds = ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    assert np.array_equal(strength_field(X, bounds, layers, 3), strength_field(X, bounds, tree, 3))
    assert LAYER_TYPES["radial"]().inner == 0.2
    with pytest.raises(InputError, match="kind"):
        as_layer({"kind": "granite"})


def test_defaults_name_the_package_presets_after_the_config_folder(tmp_path):
    """``defaults: [strength/bricks]`` in a config anywhere reads the shipped preset; a file of that name
    next to the config comes first; an unknown name is refused with the presets that exist; a file that
    names itself is a cycle."""
    from fracture.pipeline import presets

    cfg = load_config(write(tmp_path / "mine.yaml", "defaults: [strength/bricks, example]\n"))
    assert cfg.strength.layers[0].kind == "bricks" and cfg.refine.search == "graphcut"
    assert cfg.input.exterior == str((presets.root() / "meshes" / "wall.obj").resolve())
    (tmp_path / "strength").mkdir()
    write(tmp_path / "strength" / "bricks.yaml", "strength: {layers: [{kind: radial}]}\n")
    assert load_config(tmp_path / "mine.yaml").strength.layers[0].kind == "bricks"  # example's own layers last
    assert load_config(write(tmp_path / "own.yaml", "defaults: [strength/bricks]\n")).strength.layers[0].kind == \
        "radial"
    message, _ = _error(tmp_path, "defaults: [strength/granite]\n")
    assert "included config 'strength/granite' not found" in message
    assert "strength/bricks" in message and "strength/marble" in message and "bunny" in message
    message, _ = _error(tmp_path, "defaults: [../../../etc/passwd]\n")
    assert "not found" in message
    write(tmp_path / "self.yaml", "defaults: [self]\n")
    with pytest.raises(ConfigError, match="cycle of defaults"):
        load_config(tmp_path / "self.yaml")
    listed = subprocess.run([sys.executable, "-m", "fracref", "presets"], capture_output=True, text=True)
    assert listed.returncode == 0
    names = [line.split()[0] for line in listed.stdout.splitlines()]
    assert names == presets.names() and {"example", "bunny", "strength/bricks"} <= set(names)
