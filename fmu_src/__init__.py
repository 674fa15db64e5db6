"""The FMUs around ``models``: the variable table (``variables``), the pythonfmu slaves (``railcar``,
``railcar_estimator``, ``ato_controller`` on ``adapter``), the FMI glue in C (``c/``) and the
packaging of every FMU (``build/``, run by build.py)."""
