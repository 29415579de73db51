"""ersac_hil: the learner (critic, ERSAC), its daemon, the robot-side agent and the CLI."""


def __getattr__(name: str) -> str:
    # __version__ on first use: importlib.metadata costs ~20 ms, and ``ersac_hil.cli`` wants its
    # start-up's SIGINT handler in before anything slow (ersac_hil.lifecycle)
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version
    try:
        found = version("ersac-hil")
    except PackageNotFoundError:  # run from a source tree that was never installed
        found = "0+unknown"
    globals()["__version__"] = found
    return found
