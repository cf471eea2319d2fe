"""Flights: the Cessna Citation and the van in MuJoCo, the Earth model, the GPS receiver and the GPS/INS filter (seed chapter 5, paper section 4)."""
