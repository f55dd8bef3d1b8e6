"""The training progress bar: steps done of the budget, the remaining time, loss and PSNR."""

from __future__ import annotations


class Progress:
    """A tqdm bar over the step budget (its ETA is the remaining time) on stderr, shown only when
    stderr is a terminal (tqdm's ``disable=None``: a log file gets no bar); disabled: a no-op."""

    def __init__(self, name: str, steps: int, start: int, enabled: bool) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(
            total=steps,
            initial=start,
            disable=None if enabled else True,
            desc=f"train {name}",
            unit="step",
            dynamic_ncols=True,
            leave=False,
        )

    def step(self) -> None:
        self.bar.update(1)

    def show(self, entry: dict) -> None:
        self.bar.set_postfix(loss=f"{entry['loss']:.2e}", psnr=f"{entry['psnr']:.2f}")

    def close(self) -> None:
        self.bar.close()
