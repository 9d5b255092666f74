"""The launch system: a YAML launch file (``description``) becomes a running node graph
(``launcher``); the packaged launch files (``*.yaml``) live here too."""
