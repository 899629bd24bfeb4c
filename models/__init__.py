"""The twin's static MJCF scene (``scene.xml``, ``rig.xml``, ``board.xml``): the files here, at the repository's top,
are installed as the package ``twin.models`` (``pyproject.toml`` maps this folder into the package) and read through
:func:`twin.resources.model_file`."""
