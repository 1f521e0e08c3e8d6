"""benchmarks/label_noise.py: the full-preset ζσ cards listed beside the grid (pairwise only, first folder wins)."""


from rba.core.fileio import save_json
from rba.domains import get_domain
from tests.benchmark_scripts import load_benchmark

label_noise = load_benchmark("label_noise")


def _card(folder, domain: str, mode: str, accuracy: float) -> None:
    labels = {"mode": mode, "max_pairs": 1000, "noise": 0.1} if mode == "pairwise" else {}
    save_json(folder / domain / "ranker-onehot.json",
              {"training": {"labels": labels, "config": {"steps": 800}},
               "held_out": {name: {"pairwise_accuracy": accuracy} for name in get_domain(domain).attribute_names}})


def test_trained_rows_take_the_first_folder_with_a_pairwise_card(tmp_path):
    shipped, trial = tmp_path / "models", tmp_path / "trial"
    _card(shipped, "walker", "ordering", 0.99)  # a perfect-order card is not listed: the trial's pairwise one is
    _card(trial, "walker", "pairwise", 0.93)
    _card(shipped, "manipulator", "pairwise", 0.94)
    _card(trial, "manipulator", "pairwise", 0.5)  # shadowed by the shipped pairwise card
    rows = label_noise.trained_rows([shipped, trial], ["walker", "manipulator", "snake"])
    assert [(r["domain"], r["mean_accuracy"]) for r in rows] == [("walker", 0.93), ("manipulator", 0.94)]
