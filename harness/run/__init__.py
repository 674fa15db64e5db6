"""One run: scenario TOML -> resolved setup -> closed loop on an FMU -> RunResult; replay, plan, regress."""
