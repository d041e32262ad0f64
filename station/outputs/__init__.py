"""Outputs: what a calibration gives people and other programs. The parameter file
(checksummed, verified), the exports (robot file, URDF), the HTML report and its
figures, and the display units (mm and degrees) every room shows numbers in. Renders what
it is given (a fit's outcome, duck-typed); imports recording/ only."""
