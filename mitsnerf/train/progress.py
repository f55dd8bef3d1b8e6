"""The training progress: a bar over the steps done of the budget, the remaining time, loss and PSNR, on a
terminal; and a line on stderr at every tenth of the budget, terminal or not (:func:`mitsnerf.outputs.progress_log`,
so that a log file shows how far training is)."""

from __future__ import annotations

from mitsnerf.outputs import progress_log


class Progress:
    """A tqdm bar over the step budget (its ETA is the remaining time) on stderr, shown only when
    stderr is a terminal (tqdm's ``disable=None``: a log file gets no bar), and progress lines; disabled: a no-op."""

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
        self.name, self.steps, self.every = name, steps, max(1, steps // 10)
        self.next = start + self.every
        self.log = progress_log(enabled)
        self.log(f"[train] {name}: steps {start} to {steps} ...")

    def step(self) -> None:
        self.bar.update(1)

    def show(self, entry: dict) -> None:
        """A history entry: on the bar, and as a line once a tenth of the budget has passed since the last one."""
        self.bar.set_postfix(loss=f"{entry['loss']:.2e}", psnr=f"{entry['psnr']:.2f}")
        if entry["step"] >= self.next or entry["step"] == self.steps:
            self.next = entry["step"] + self.every
            self.log(f"[train] {self.name}: step {entry['step']} of {self.steps}, loss {entry['loss']:.3g}, "
                     f"training views' PSNR {entry['psnr']:.2f} dB, {entry['seconds']:.0f} s")

    def close(self) -> None:
        self.bar.close()
