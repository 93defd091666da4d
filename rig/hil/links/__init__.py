"""Links to boards: what replay needs of one (`base.BoardLink`), a pyserial port
carrying protocol frames (`serial_port`) and a Crazyflie link through cflib's drivers
(`crtp`). Which target opens which link is `rig.hil.targets`."""

from rig.hil.links.base import BoardLink, LinkError
from rig.hil.links.crtp import CrtpLink, open_crazyflie
from rig.hil.links.serial_port import Link, open_url

__all__ = ["BoardLink", "LinkError", "Link", "CrtpLink", "open_url", "open_crazyflie"]
