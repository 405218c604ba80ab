"""A switch's health over its throws: fault levels, trends and throws to a limit (prognosis), throw features and
their bands, and alarms that stay latched until acknowledged."""
