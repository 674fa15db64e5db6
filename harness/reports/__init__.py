"""Reports that only draw: summary tables, plots and the library table from computed metrics."""
