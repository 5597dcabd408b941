"""balloon-wind ground station: WIND_COV in, display, logs, plots and scores out."""
