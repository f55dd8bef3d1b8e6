"""Training: a short loop (:mod:`.loop`) over small parts that can each be tested alone.

- :mod:`.config`: the budget (steps) and the settings every method shares;
- :mod:`.data`: the training pixels and their (jittered) rays;
- :mod:`.step`: one step's loss, by the model's protocol;
- :mod:`.schedule`: the learning rate as a function of the step, the step's random numbers;
- :mod:`.monitor`: NaN and divergence checks;
- :mod:`.clock`: training seconds, evaluation excluded;
- :mod:`.checkpointing`: when checkpoints are written, and stopping on SIGINT/SIGTERM/SIGHUP;
- :mod:`.progress`: the progress bar;
- :mod:`.threads`: one thread for bit-identical runs (`--deterministic`; LLVM only, refused on CUDA).
"""

from mitsnerf.train.config import TrainConfig
from mitsnerf.train.data import PixelData
from mitsnerf.train.loop import TrainResult, TrainState, make_optimizer, train
from mitsnerf.train.schedule import learning_rate, step_rng

__all__ = ["PixelData", "TrainConfig", "TrainResult", "TrainState", "learning_rate", "make_optimizer", "step_rng",
           "train"]
