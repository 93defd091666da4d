"""rig.diagnosis — why simulation and reality disagree: a recording's residual channels
against a simulation of its own flight (`channels`), where they differ before any fit
(`mismatch`), the catalog's effects as fitted (`candidates`), naming them (`selection`),
what a flight can tell apart (`identifiability`), the airframe's lean as each IMU sensor
measures it (`lean`), the shaped searches (`nlos_mixture`,
`region_scan`, `floor_error`, `imu_spectrum`), robust estimators (`robust`), the
diagnosis (`diagnose`) and its findings — the report.json contract (`findings`), the comparison
against a control recording (`compare`), a finding in words (`wording`), report.md and
its plots (`report`), and models of several flights combined into a simulation config
(`combine`).

May import: `rig.data`, `rig.estimator`, `rig.sim`. matplotlib only in `report`.
"""
