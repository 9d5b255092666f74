"""Pictures: a frame's map as a PNG (`map_figure`) and as a rotatable HTML page (`map_page`),
the paper's figures of a study (`paper`) and the noise study's (`noise`). matplotlib is loaded
only when drawing."""
