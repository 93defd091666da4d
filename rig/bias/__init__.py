"""rig.bias — learning the TDOA bias correction: the dataset of features and labels from
flights with ground truth (`dataset`), each flight's constant tag offset in its errors
(`tag_offset`, which `--untranslated` removes from the labels), training and provenance
(`train`), the link-bias model's fit (`calibrate`) and the shipped models
(`models/`). The network's format and its use by the estimator live in
`rig.estimator.bias_net`.

May import: `rig.data`, `rig.estimator`, `rig.sim` (the anchors' world geometry).
torch is imported only inside training.
"""
