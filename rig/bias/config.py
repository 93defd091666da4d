"""How training is configured: what `rig train`'s options mean, importable without
torch, scipy or the dataset (the command line builds its parser from it)."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.estimator.bias_net import FORMS, INPUTS

FEATURES_FROM = ("estimate", "truth")   # the tag pose the features are computed from

RESTART_STRIDE = 1000
# How the kept restart is chosen: the estimator's mean 3D RMSE on the validation flights
# (closed loop), or the validation TDOA error (no replay; also used with excluded anchors,
# whose measurements the validation flights' replays would correct).
SELECT_BY = ("rmse_3d", "mse")


@dataclass
class TrainConfig:
    seed: int = 0               # the flight split and, through init_seed, the initialisations
    restarts: int = 3
    first_restart: int = 0      # retrain one chosen restart alone: first_restart=i, restarts=1
    select_by: str = SELECT_BY[0]
    batch_size: int = 256
    learning_rate: float = 2e-3
    weight_decay: float = 1e-5
    max_epochs: int = 60
    patience: int = 5           # epochs without validation improvement before stopping
    features: list[int] = field(default_factory=lambda: list(range(INPUTS)))  # others are zeroed (pair form)
    # "link": one network of a tag-anchor link's features, TDOA bias = g(B) - g(A); "pair":
    # a network of the measurement's 14 features (rig.estimator.bias_net)
    form: str = FORMS[0]

    def __post_init__(self) -> None:
        if self.restarts < 1:
            raise ValueError(f"restarts must be at least 1, got {self.restarts}")
        if not 0 <= self.first_restart <= RESTART_STRIDE - self.restarts:
            raise ValueError(f"restarts {self.first_restart}..{self.first_restart + self.restarts - 1} "
                             f"are outside 0..{RESTART_STRIDE - 1}")
        if self.select_by not in SELECT_BY:
            raise ValueError(f"select_by must be one of {SELECT_BY}, got {self.select_by!r}")
        if self.form not in FORMS:
            raise ValueError(f"form must be one of {FORMS}, got {self.form!r}")
        if self.form == "link" and sorted(self.features) != list(range(INPUTS)):
            raise ValueError("a feature subset applies to the pair form only (the link form takes a link's 7)")

    def init_seed(self, restart: int) -> int:
        """Restart i of seed s initialises with s * RESTART_STRIDE + i: two seeds never share one."""
        return self.seed * RESTART_STRIDE + restart


ALL_FEATURES = list(range(INPUTS))
# Without the anchors' orientation: drop the tag's azimuth and elevation in each anchor's
# frame (features 6, 7, 10, 11); the anchors seen from the tag's body frame stay.
WITHOUT_ANCHOR_ORIENTATION = [0, 1, 2, 3, 4, 5, 8, 9, 12, 13]
FEATURE_SETS = {"14": ALL_FEATURES, "10": WITHOUT_ANCHOR_ORIENTATION}
