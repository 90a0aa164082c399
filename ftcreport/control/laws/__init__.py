"""The built-in schemes' compiled laws (the scheme API's contract, ftcreport.schemes.api).

Two dispatchers, so that the built-in schemes share two compiled loops: :mod:`.passive` (nominal,
oracle, switching, adaptive: ``P.kind`` chooses) and :mod:`.active` (Farza's observer or the UKF).
"""
