"""The position engine: windows, the window filter, its factor graph, the stage's solve and its
covariances."""
