"""How a saved run that lacks a setting is read (:func:`mitsnerf.config.saved_readings`), for every built-in method and
the training and evaluation settings, kept in ``saved_settings.json``: a default changed without declaring on the
field what runs saved before the setting existed trained with (``param(NEW, since=(VERSION, OLD))``) fails here, as a
setting added without a thought for the runs saved before it.

After declaring (or when a new setting's default is what older runs did), write the file again::

    .venv/bin/python -m tests.methods.test_saved_settings > tests/methods/saved_settings.json
"""

from __future__ import annotations

import json
from pathlib import Path

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf.config import saved_readings

KEPT = Path(__file__).with_name("saved_settings.json")


def current() -> dict[str, dict]:
    """``{"method NAME" | "train" | "eval": {dotted key: what a saved run lacking it reads as}}``."""
    from mitsnerf.methods import methods
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import EvalConfig

    out = {f"method {name}": saved_readings(m.config_type) for name, m in methods().items()
           if m.source.kind == "built-in"}
    return {**out, "train": saved_readings(TrainConfig), "eval": saved_readings(EvalConfig)}


def test_no_setting_changed_how_a_run_saved_without_it_reads():
    kept, now = json.loads(KEPT.read_text()), json.loads(json.dumps(current()))
    problems = []
    for table in sorted(set(kept) | set(now)):
        old, new = kept.get(table, {}), now.get(table, {})
        for key in sorted(set(old) | set(new)):
            if key not in new:
                problems.append(f"{table}: {key} is gone (a run saved with it is now refused as an unknown field)")
            elif key not in old:
                problems.append(f"{table}: {key} is new: a run saved before it reads {json.dumps(new[key])}; if it "
                                f"trained otherwise, declare param(..., since=(VERSION, VALUE)) on the field")
            elif old[key] != new[key]:
                problems.append(f"{table}: {key}: a run saved without it read {json.dumps(old[key])}, now "
                                f"{json.dumps(new[key])}: declare param(..., since=(VERSION, VALUE)) on the field, "
                                "VALUE what runs saved before it existed trained with")
    assert not problems, "\n".join(problems + [f"then write {KEPT.name} again (its module docstring says how)"])


if __name__ == "__main__":
    print(json.dumps(current(), indent=1, sort_keys=True))
