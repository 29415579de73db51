"""``results.md``: the sizes line names every recorded experiment's own sizes (a directory run
one experiment at a time keeps each one's), and the lifting section names its learner."""
from __future__ import annotations

from ersac_hil.reproduce.results import markdown


def test_the_sizes_of_every_recorded_experiment_are_listed():
    meta = {"sizes": {"lifting": {"lifting_seeds": 10, "lifting_interleave_every": 0},
                      "contexts": {"context_episodes": 5}}, "quick": False, "pairs": 2, "timing": {}}
    text = markdown({"meta": meta, "targets": []})
    assert '- lifting: `{"lifting_seeds": 10, "lifting_interleave_every": 0}`' in text
    assert '- contexts: `{"context_episodes": 5}`' in text and "pairs 2, full sizes" in text


def test_the_lifting_section_names_its_learner():
    lifting = {"stages": ["initial"], "per_seed": {}, "learner": "interleaved offline search every 5 updates"}
    assert "## Lifting (kappa 0, interleaved offline search every 5 updates)" in markdown({"lifting": lifting})
    del lifting["learner"]  # results written before the option: the paper's algorithm
    assert "## Lifting (kappa 0, the paper's Algorithm 1)" in markdown({"lifting": lifting})
