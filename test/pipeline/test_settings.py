"""One settings path: SPECS, the per-stage settings, the presets, config/ and the CLI flags."""

from __future__ import annotations

import json
import os
import typing

from mvbb_ros import decompose, grasp_hypotheses, PipelineSettings, process_points
from mvbb_ros.cli.main import build_parser, main
from mvbb_ros.cli.options import settings_from_args
from mvbb_ros.evaluation.synthetic import segmented_object_cloud
from mvbb_ros.geometry.decomposition.result import DecompositionSettings
from mvbb_ros.geometry.decomposition.split import SPLIT_MEASURES
from mvbb_ros.geometry.grasping.hypotheses import APPROACH_AXES, GraspSettings, STRATEGIES
from mvbb_ros.geometry.grasping.refinement_settings import RefinementSettings
from mvbb_ros.geometry.views.completion import COMPLETIONS
from mvbb_ros.pipeline.scene import SceneSettings
from mvbb_ros.pipeline.settings import PRESETS, STAGES, validate_setting
from mvbb_ros.pipeline.settings_text import (
    config_files,
    format_assignment,
    parse_assignments,
    read_params_file,
)
from mvbb_ros.pipeline.specs import SPEC_BY_NAME, SPECS, STAGE_DEFAULT
from mvbb_ros.pipeline.stage_settings import (
    ExecutionSettings,
    FilterSettings,
    NodeSettings,
    ViewSettings,
)
import numpy as np
import pytest
from support.data import REPO_ROOT

PARAMETER_TYPES = {bool: bool, int: int, float: float, str: str, list: tuple}


@pytest.fixture(scope='module')
def mug() -> np.ndarray:
    return segmented_object_cloud('mug', seed=0)


def test_every_spec_sets_a_typed_field_of_a_stage():
    for spec in SPECS:
        assert spec.stage in STAGES.values(), spec.name
        hints = typing.get_type_hints(spec.stage)
        assert spec.attribute in hints, f'{spec.name}: {spec.stage.__name__} has no field'
        accepted = PARAMETER_TYPES[spec.kind]
        stage_default = getattr(spec.stage(), spec.attribute)
        assert stage_default is None or isinstance(stage_default, accepted), spec.name
        if spec.node_default is not STAGE_DEFAULT:
            assert spec.node_default != spec.stage_default, f'{spec.name}: written twice'
    names = [spec.name for spec in SPECS]
    assert len(names) == len(set(names))
    assert list(STAGES.values()) == [
        FilterSettings,
        SceneSettings,
        ViewSettings,
        DecompositionSettings,
        GraspSettings,
        RefinementSettings,
        ExecutionSettings,
        NodeSettings,
    ], 'pipeline order'
    for stage in STAGES.values():
        assert any(spec.stage is stage for spec in SPECS), f'{stage.__name__} has no setting'


def test_choice_lists_are_defined_once_with_their_stage():
    assert SPEC_BY_NAME['split_measure'].choices is SPLIT_MEASURES
    assert SPEC_BY_NAME['grasp_strategy'].choices is STRATEGIES
    assert SPEC_BY_NAME['approach_axis'].choices is APPROACH_AXES
    assert SPEC_BY_NAME['shape_completion'].choices is COMPLETIONS
    for spec in SPECS:
        if spec.choices:
            assert spec.stage_default == spec.choices[0], (
                f"{spec.name}: the first choice is the stage's default"
            )


def test_node_defaults_come_from_specs_and_the_paper_preset_from_the_stages():
    node = PipelineSettings()
    assert node.parameters() == {spec.name: spec.default for spec in SPECS}
    assert node.decomposition.min_points == 25 and node.decomposition.max_boxes == 16
    assert node.filtering.voxel_size == 0.005 and node.filtering.outlier_neighbors == 20
    paper = PipelineSettings.paper()
    assert PRESETS == {'node': node, 'paper': paper}
    assert paper.decomposition == DecompositionSettings()
    assert paper.filtering == FilterSettings() and paper.grasps == GraspSettings()
    assert paper.node == NodeSettings()
    assert paper.parameters() == {spec.name: spec.stage_default for spec in SPECS}
    assert paper.decomposition.min_points == 10 and paper.decomposition.max_boxes is None


@pytest.mark.parametrize('preset', list(PRESETS))
def test_parameter_values_round_trip(preset):
    settings = PRESETS[preset]
    assert PipelineSettings().updated(settings.parameters()) == settings
    assignments = [format_assignment(name, value) for name, value in settings.parameters().items()]
    assert parse_assignments(assignments) == settings.parameters()


def test_unset_values_map_to_none_in_the_stages():
    settings = PipelineSettings().updated({'max_boxes': 0, 'up_direction': [0, 0, 2.0]})
    assert settings.decomposition.max_boxes is None
    assert settings.view.up == (0.0, 0.0, 2.0)
    assert settings.updated({'up_direction': []}).view.up is None
    assert settings.value('max_boxes') == 0 and settings.value('up_direction') == [0.0, 0.0, 2.0]
    with pytest.raises(ValueError, match='max_boxes must be in'):
        settings.updated({'max_boxes': -1})


def test_config_files_are_made_from_specs():
    for name, text in config_files().items():
        path = REPO_ROOT / 'config' / name
        assert path.read_text() == text, f'{path} is out of date: run tools/make_config.py'
        for spec in SPECS:
            assert spec.name in text


def test_the_paper_preset_runs_the_papers_algorithm(mug):
    """process_points with the paper preset is decompose() and grasp_hypotheses() as they are."""
    paper = process_points(mug, PipelineSettings.paper())
    decomposition = decompose(mug)
    grasps = grasp_hypotheses(decomposition)
    assert len(paper.objects) == 1 and paper.objects[0].shape.method == 'none'
    assert paper.objects[0].decomposition.settings == decomposition.settings
    assert [box.volume for box in paper.leaves] == [box.volume for box in decomposition.leaves]
    assert [g.position.tolist() for g in paper.grasps] == [g.position.tolist() for g in grasps]
    node = process_points(mug)
    assert len(node.leaves) != len(paper.leaves), 'the filters and min_points change the result'


def _args(*arguments: str):
    return build_parser().parse_args(['decompose', 'cloud.npy', *arguments])


def test_flags_are_the_parameter_names_in_both_spellings(capsys):
    dashed = settings_from_args(_args('--gain-threshold', '0.9', '--grasp-strategy', 'smallest'))
    underscored = settings_from_args(
        _args('--gain_threshold', '0.9', '--grasp_strategy', 'smallest')
    )
    assert dashed == underscored
    assert dashed.decomposition.gain_threshold == 0.9 and dashed.grasps.strategy == 'smallest'
    assert settings_from_args(_args('-t', '0.9')).decomposition.gain_threshold == 0.9
    vectors = settings_from_args(_args('--up-direction', '0', '0', '1', '--max-boxes', '0'))
    assert vectors.view.up == (0.0, 0.0, 1.0) and vectors.decomposition.max_boxes is None
    assert settings_from_args(_args()) == PipelineSettings()
    with pytest.raises(SystemExit):
        main(['decompose', '--help'])
    help_text = capsys.readouterr().out
    for spec in SPECS:
        assert (f'--{spec.name.replace("_", "-")}' in help_text) == (
            spec.stage is not NodeSettings
        )
    with pytest.raises(SystemExit):
        _args('--strategy', 'smallest')  # the flag is named like the parameter now


def test_preset_then_file_then_p_then_flags(tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text(
        '/**:\n  ros__parameters:\n    min_points: 12\n    seed: 3\n    standoff: 1\n'
    )
    args = _args(
        '--preset', 'paper', '--params-file', str(params), '-p', 'seed:=4', '-p', 'standoff:=0.2',
        '--standoff', '0.3',
    )  # fmt: skip
    settings = settings_from_args(args)
    assert settings.filtering == FilterSettings(), 'the paper preset: no filters'
    assert settings.decomposition.min_points == 12 and settings.decomposition.seed == 4
    assert settings.grasps.standoff == 0.3


def test_bad_values_are_refused_with_the_nodes_reason(tmp_path, capsys):
    cloud = tmp_path / 'cloud.npy'
    np.save(cloud, np.random.default_rng(0).uniform(size=(200, 3)))
    assert main(['decompose', str(cloud), '--gain-threshold', '1.5']) == 1
    assert 'gain_threshold must be in [0.0, 1.0], got 1.5' in capsys.readouterr().err
    assert main(['decompose', str(cloud), '-p', 'voxel_size:=-1']) == 1
    assert 'voxel_size must be in' in capsys.readouterr().err
    assert main(['decompose', str(cloud), '--voxel-size', '1']) == 1
    assert 'fewer than min_points = 25' in capsys.readouterr().err


def test_decompose_with_the_paper_preset_writes_the_papers_boxes(tmp_path, mug):
    cloud, out = tmp_path / 'mug.npy', tmp_path / 'mug.json'
    np.save(cloud, mug)
    assert main(['decompose', str(cloud), '--preset', 'paper', '--json', str(out)]) == 0
    document = json.loads(out.read_text())
    decomposition = decompose(mug.astype(np.float64))
    volumes = [leaf['box']['volume'] for leaf in document['leaves']]
    assert volumes == [box.volume for box in decomposition.leaves]
    assert len(document['grasps']) == len(grasp_hypotheses(decomposition))
    assert document['parameters'] == PipelineSettings.paper().parameters()
    assert document['filter_counts']['finite'] == document['filter_counts']['inliers'] == len(mug)


@pytest.mark.parametrize('name', ['gripper_franka_hand.yaml', 'gripper_robotiq_2f85.yaml'])
def test_the_gripper_files_describe_a_hand_the_settings_accept(name):
    """Each hand's parameter file loads into the node's settings and sets the whole hand."""
    values = read_params_file(REPO_ROOT / 'config' / name)
    hand = {
        'gripper_max_width',
        'finger_length',
        'finger_pad_size',
        'finger_thickness',
        'palm_width',
        'palm_depth',
        'palm_height',
    }
    assert set(values) == hand
    settings = PipelineSettings().updated(values)
    assert settings.refinement.palm_width == values['palm_width']
    assert settings.grasps.gripper_max_width == values['gripper_max_width']
    assert values['palm_width'] >= values['gripper_max_width'] + 2 * values['finger_thickness']


def test_workers_default_to_the_cores_the_process_may_use_and_refuse_fewer_than_one():
    cores = len(os.sched_getaffinity(0))
    assert PipelineSettings().execution.workers == min(cores, 8)
    assert PipelineSettings.paper().execution == ExecutionSettings()
    assert PipelineSettings().updated({'workers': 3}).execution.workers == 3
    for bad in (0, -1, 65, 1.5, True, '2'):
        assert validate_setting('workers', bad) is not None, bad
        with pytest.raises(ValueError, match='workers must be'):
            PipelineSettings().updated({'workers': bad})
    # The parameter files are the same on every machine: they name the default.
    for name, text in config_files().items():
        assert '# workers: the cores this process may use, at most 8' in text, name
        assert 'workers' not in read_params_file(REPO_ROOT / 'config' / name), name
    assert parse_assignments([format_assignment('workers', 2)]) == {'workers': 2}
