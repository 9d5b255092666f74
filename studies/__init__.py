"""Studies as files: parameter grids of sweeps, run on local processes or a Dask cluster,
stored per case under a hash of its inputs (`vibrissa.studies.grid_file`,
`vibrissa.studies.grid_run`)."""
