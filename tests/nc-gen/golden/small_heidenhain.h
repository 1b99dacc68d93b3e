0 BEGIN PGM FORMLOOP MM 1;
formloop small test path(2 passes) 2;
ball - end tool T2 radius 3.000 mm;
programmed point = ball tip [TOOL CALL:length L of the tool table to the ball tip];
2 passes 3 TOOL CALL 2 Z S12000 4 L Z + 10.000 R0 FMAX M3 5;
cut 6;
pass 0 7 L X - 7.500 Y - 2.000 R0 FMAX 8 L X - 7.500 Y - 2.000 Z - 1.250 R0 F300 9 L X - 2.500 Y - 2.000 Z -
    0.500 R0 F1200 10 L X + 2.500 Y - 2.000 Z + 0.000 R0 11 L X + 7.500 Y - 2.000 Z + 0.750 R0 12 L Z +
    10.000 R0 FMAX 13;
pass 1 14 L X + 7.500 Y + 0.500 R0 FMAX 15 L X + 7.500 Y + 0.500 Z + 0.500 R0 F300 16 L X + 2.500 Y + 0.500 Z -
    0.125 R0 F1200 17 L X - 2.500 Y + 0.500 Z - 2.000 R0 18 L X - 7.500 Y + 0.500 Z - 3.500 R0 19 L Z +
    10.000 R0 FMAX M30 20 END PGM FORMLOOP MM
