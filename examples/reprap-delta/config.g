; A RepRapFirmware delta (config.g excerpt): diagonals 360 mm, radius 190 mm,
; homed height 420 mm, print radius 150 mm, no corrections yet.
M665 L360 R190 H420 B150 X0 Y0 Z0 ; geometry
M666 X0 Y0 Z0 A0 B0               ; endstop adjustments, bed tilt
M558 P5                            ; probe
