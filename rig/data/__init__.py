"""rig.data — the flights as files: the Crazyflie uSD event-log decoder (`usdlog`), anchor
surveys and their frames (`survey`), MCAP recordings in SI units (`recording`) and their binary
cache (`cache`), the importer that turns a log and a survey into a recording (`importer`), where the shared
data and the shipped files are (`paths`), the exceptions that mean bad input
(`errors`) and output files written whole (`files`).

May import: the standard library, numpy, scipy and mcap; nothing else of `rig`.
"""
