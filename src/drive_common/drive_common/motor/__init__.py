"""What the drive knows of its motor and inverter: the nameplate, the inverter rating and the
commissioning record (no plant model)."""
