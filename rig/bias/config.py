"""How training is configured: what `rig train`'s options mean, importable without
torch, scipy or the dataset (the command line builds its parser from it)."""

from __future__ import annotations

from dataclasses import dataclass

from rig.estimator.bias_net import FORMS, shape

FEATURES_FROM = ("estimate", "truth")   # the tag pose the features are computed from
# The estimator the recipe replays, for the features' estimated pose and for choosing a
# restart: without the blocked-anchor weighting (session 83), as the networks that chose
# the weighting by transfer were trained. Changing it changes the recipe.
RECIPE_ESTIMATOR = {"anchor_bias_c": 0.0}

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
    # "link": one network of a tag-anchor link's features, TDOA bias = g(B) - g(A); "pair":
    # a network of the measurement's 14 features (rig.estimator.bias_net)
    form: str = FORMS[0]
    # the form's features the network sees (its 14 or its link's 7); the others are zeroed
    features: list[int] | None = None
    # link form: each anchor's own range offset, learnt beside the shared network and
    # bounded (ANCHOR_OFFSET_BOUND_M); an anchor never seen in training gets 0
    anchor_offsets: bool = False
    # each training and validation flight's constant tag offset removed from its labels
    # (rig.bias.tag_offset): the correction then carries none, as no flight can tell one
    # from where the tag really is
    untranslated: bool = False

    def __post_init__(self) -> None:
        if self.restarts < 1:
            raise ValueError(f"restarts must be at least 1, got {self.restarts}")
        if self.max_epochs < 1:
            raise ValueError(f"max_epochs must be at least 1, got {self.max_epochs}")
        if not 0 <= self.first_restart <= RESTART_STRIDE - self.restarts:
            raise ValueError(f"restarts {self.first_restart}..{self.first_restart + self.restarts - 1} "
                             f"are outside 0..{RESTART_STRIDE - 1}")
        if self.select_by not in SELECT_BY:
            raise ValueError(f"select_by must be one of {SELECT_BY}, got {self.select_by!r}")
        if self.form not in FORMS:
            raise ValueError(f"form must be one of {FORMS}, got {self.form!r}")
        n_in = shape(self.form)[0]
        if self.features is not None and (not self.features or not set(self.features) <= set(range(n_in))):
            raise ValueError(f"the {self.form} form's features are 0..{n_in - 1}, got {self.features}")
        if self.anchor_offsets and self.form != "link":
            raise ValueError("anchor offsets belong to the link form")

    @classmethod
    def with_features(cls, name: str, **kwargs) -> "TrainConfig":
        """The configuration of a named feature set (FEATURE_SETS), which fixes the form."""
        form, features, anchor_offsets = FEATURE_SETS[name]
        return cls(form=form, features=features, anchor_offsets=anchor_offsets, **kwargs)

    def kept_features(self) -> list[int]:
        return list(range(shape(self.form)[0])) if self.features is None else sorted(self.features)

    def init_seed(self, restart: int) -> int:
        """Restart i of seed s initialises with s * RESTART_STRIDE + i: two seeds never share one."""
        return self.seed * RESTART_STRIDE + restart


# Physical bound of an anchor's own range offset: a DW1000 antenna delay miscalibrated by
# 1 ns is 0.3 m; more is not a delay.
ANCHOR_OFFSET_BOUND_M = 0.3

# Without the anchors' orientation: drop the tag's azimuth and elevation in each anchor's
# frame (features 6, 7, 10, 11); the anchors seen from the tag's body frame stay.
WITHOUT_ANCHOR_ORIENTATION = [0, 1, 2, 3, 4, 5, 8, 9, 12, 13]
# A link's features that every anchor shares (bias_net.h, BN_LINK_A): the tag's azimuth
# and elevation in the anchor's frame (the anchor antenna's pattern) and the anchor's
# elevation from the tag (the tag's antenna and the airframe). Left out: the anchor's
# position relative to the tag in the world and its heading-free azimuth, which tell
# one anchor from another (each sits in its own quadrant of the room), so a network
# fed them learns per-anchor fields that say nothing about an anchor it never saw.
LINK_SHARED = [3, 5, 6]
# `rig train --features`: name -> (form, features, anchor offsets)
FEATURE_SETS = {"14": ("pair", None, False), "10": ("pair", WITHOUT_ANCHOR_ORIENTATION, False),
                "7": ("link", None, False), "shared": ("link", LINK_SHARED, True)}
DEFAULT_FEATURE_SET = {"pair": "14", "link": "7"}
