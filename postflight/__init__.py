"""Post-flight: log readers, the fixed-interval smoother, reprocessing, and the science products
(data model, averages, NetCDF, plots)."""
