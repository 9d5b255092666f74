"""File formats: scene files and robot descriptions (``scene_file``), the results of
``vibrissa simulate`` (``scene_results``), CSV text (``csv_text``), strict YAML numbers
(``yaml_numbers``) and files written whole or not at all (``files``).

Below the node runtime: a command that only reads a scene or writes a CSV loads no ZeroMQ.
"""
