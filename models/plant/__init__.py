"""The plant: car dynamics (eq. (1)-(2)), track profiles, sensors and seeded noise."""
