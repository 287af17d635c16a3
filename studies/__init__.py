"""The shipped study files, installed as the data package ``service.shipped``.

This folder is the repository's home of the shipped studies (``*.yaml``), the nightly suite
(``nightly/``) and its baselines (``baselines/``); ``pyproject.toml`` maps it to the package
``service.shipped`` so that an installed impactcell finds them from any folder. Read them through
:mod:`service.studies.shipped`, never by path.
"""
