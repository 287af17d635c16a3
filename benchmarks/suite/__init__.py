"""The maintained speed suite, run by asv (``asv.conf.json`` at the repository's root; results
stay outside git, in ``.asv/``). It imports only the installed packages (``worker``,
``service``), so asv times each commit's own code."""
