"""Tests for mvbb_ros.evaluation.shared_data: one rule that finds the shared real data."""

from mvbb_ros.evaluation import shared_data
import pytest


@pytest.fixture
def no_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(shared_data.ENVIRONMENT, raising=False)


def test_the_environment_variable_names_the_folder(tmp_path, monkeypatch):
    monkeypatch.setenv(shared_data.ENVIRONMENT, str(tmp_path / 'elsewhere'))
    assert shared_data.shared_data_folder(tmp_path / 'checkout') == tmp_path / 'elsewhere'


@pytest.mark.usefixtures('no_variable')
def test_a_checkout_finds_the_data_beside_it(tmp_path):
    (tmp_path / 'shared' / 'data').mkdir(parents=True)
    checkout = tmp_path / 'main'
    checkout.mkdir()
    assert shared_data.shared_data_folder(checkout) == tmp_path / 'shared' / 'data'


@pytest.mark.usefixtures('no_variable')
def test_a_worktree_finds_the_projects_data_beside_a_parent_folder(tmp_path):
    (tmp_path / 'shared' / 'data').mkdir(parents=True)
    worktree = tmp_path / 'wt' / 'branch'
    worktree.mkdir(parents=True)
    assert shared_data.shared_data_folder(worktree) == tmp_path / 'shared' / 'data'


@pytest.mark.usefixtures('no_variable')
def test_the_nearest_data_folder_wins(tmp_path):
    (tmp_path / 'shared' / 'data').mkdir(parents=True)
    (tmp_path / 'wt' / 'shared' / 'data').mkdir(parents=True)
    worktree = tmp_path / 'wt' / 'branch'
    worktree.mkdir()
    assert shared_data.shared_data_folder(worktree) == tmp_path / 'wt' / 'shared' / 'data'


@pytest.mark.usefixtures('no_variable')
def test_without_data_the_folder_beside_the_checkout_is_named(tmp_path):
    checkout = tmp_path / 'a' / 'b' / 'main'
    checkout.mkdir(parents=True)
    folder = shared_data.shared_data_folder(checkout)
    assert folder == checkout.parent / 'shared' / 'data'
    assert not folder.exists()


def test_missing_data_says_where_it_looked_and_how_to_point_at_it(tmp_path):
    absent = tmp_path / 'scans'
    reason = shared_data.missing(absent)
    assert reason is not None
    assert str(absent) in reason
    assert shared_data.ENVIRONMENT in reason
    absent.mkdir()
    assert shared_data.missing(absent) is None
