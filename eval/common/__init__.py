"""The project's common floor, below the evaluation protocol and everything else: the canonical
data layout and its readers and writers (``layout``, ``imageio``, ``colorspace``), atomic records
(``atomic``), stated errors (``errors``), the one CLI door (``cli_entry``, ``argv``, ``cli_help``,
``cli_precheck``, the config directory ``conf``), the torch device (``device``) and the install-time
npm fetcher (``npm_package``). It imports nothing of the project above it; eval/ itself is the
protocol (docs/PROTOCOL.md).
"""
