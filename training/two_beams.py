"""TwoBeamsNet: an IMU window plus two DVL beams -> the 3-D body-frame DVL velocity
(the "MissBeamNet" case of the BeamsNet line of work: two of four beams lost).

With two beams the velocity is not determined: beams 1 and 2 (azimuths 45 and 135 deg)
leave the direction (0, -cos(theta), sin(theta)/sqrt(2)) unobserved, i.e. a mix of the
lateral and vertical velocity. The IMU has to carry it: at the DVL, the lateral
velocity follows the yaw rate through the lever arm (about -1.5 m/s per rad/s on
A-KIT), the rest is the vehicle's typical motion.

Small on purpose (training shares 2 CPU cores):
- IMU: acc and gyro stacked (6 x 100), Conv1d(6 -> 8, kernel 10, stride 10) + Tanh,
  flatten (80), Linear 80 -> 32 + ReLU;
- concatenated with the 2 beams (34), Linear 34 -> 32 + ReLU, Linear 32 -> 3;
- plus a linear path beams -> velocity (Linear 2 -> 3), initialised at the
  minimum-norm solution pinv(A_2) of the two beams' geometry.

Inputs are already normalised (see train_two_beams.py and models/two_beams.json).
"""

import torch
from torch import nn

WINDOW = 100
BEAMS = 2


class TwoBeamsNet(nn.Module):
    """forward(acc [B,3,100], gyro [B,3,100], beams [B,2]) -> velocity [B,3]."""

    def __init__(self):
        super().__init__()
        self.conv = nn.Conv1d(6, 8, kernel_size=10, stride=10)
        self.imu = nn.Linear(8 * (WINDOW // 10), 32)
        self.mix = nn.Linear(32 + BEAMS, 32)
        self.out = nn.Linear(32, 3)
        self.linear = nn.Linear(BEAMS, 3)

    def forward(self, acc: torch.Tensor, gyro: torch.Tensor, beams: torch.Tensor) -> torch.Tensor:
        x = torch.tanh(self.conv(torch.cat((acc, gyro), dim=1))).flatten(1)
        x = torch.relu(self.imu(x))
        x = torch.relu(self.mix(torch.cat((x, beams), dim=1)))
        return self.out(x) + self.linear(beams)
