"""simeval's Hydra sweeper (see user_error_sweeper.py). `hydra_plugins` is Hydra's namespace for plugins: Hydra
instantiates a sweeper only from it, and finds this one because `src/` is on the path of every entrypoint."""
