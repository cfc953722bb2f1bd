"""Slides of a puck recorded in PyBullet: identification data from an engine other than MuJoCo.

Not part of the package (``pip install pybullet`` first). A cylinder puck, 76 mm across, 30 mm
high, 0.17 kg (Bullet's cylinder primitive, whose inertia is exact), settles on a plane, is set
sliding and spinning three times (1 ms steps, Bullet's default solver), and each slide's poses
are written at 100 Hz, 50 frames, as the CSV ``dano sysid`` reads (t, centre of mass x y z [m],
quaternion w x y z). Bullet multiplies the two bodies' friction coefficients: the plane's is 1,
so the puck's is the pair's.

    python scripts/record_bullet_slides.py 0.3 b03      # writes b03_1.csv … b03_3.csv

The same puck as a DANO: ``trimesh.creation.cylinder(radius=0.038, height=0.030,
sections=96).export("puck.obj")``, then ``dano build puck.obj -o puck.dano --mass 0.17``
(docs/sysid.md, "A user's object from a second engine").
"""

import argparse

import numpy as np
import pybullet as pb

RADIUS, HEIGHT, MASS = 0.038, 0.030, 0.17
#: (linear velocity world [m/s], angular velocity world [rad/s]) of each slide
LAUNCHES = [((1.0, 0.2, 0.0), (0.0, 0.0, 6.0)), ((-0.7, 0.8, 0.0), (0.0, 0.0, -4.0)),
            ((0.3, -1.1, 0.0), (0.0, 0.0, 8.0))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("friction", type=float, help="the puck's friction coefficient (the plane's is 1)")
    parser.add_argument("prefix", help="CSV files PREFIX_1.csv … PREFIX_3.csv are written")
    args = parser.parse_args()
    pb.connect(pb.DIRECT)
    pb.setGravity(0, 0, -9.81)
    pb.setTimeStep(1e-3)
    plane = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE))
    start = [0.0, 0.0, HEIGHT / 2 + 0.002]
    puck = pb.createMultiBody(MASS, pb.createCollisionShape(pb.GEOM_CYLINDER, radius=RADIUS, height=HEIGHT),
                              basePosition=start)
    pb.changeDynamics(plane, -1, lateralFriction=1.0, restitution=0.0)
    pb.changeDynamics(puck, -1, lateralFriction=args.friction, restitution=0.0, linearDamping=0.0,
                      angularDamping=0.0)
    for k, (v, w) in enumerate(LAUNCHES):
        pb.resetBasePositionAndOrientation(puck, start, [0, 0, 0, 1])
        pb.resetBaseVelocity(puck, [0, 0, 0], [0, 0, 0])
        for _ in range(500):  # settle on the plane
            pb.stepSimulation()
        pb.resetBaseVelocity(puck, v, w)
        rows = []
        for frame in range(50):
            pos, q = pb.getBasePositionAndOrientation(puck)  # Bullet's quaternion is x, y, z, w
            rows.append([frame * 0.01, *pos, q[3], q[0], q[1], q[2]])
            for _ in range(10):
                pb.stepSimulation()
        np.savetxt(f"{args.prefix}_{k + 1}.csv", rows, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="")


if __name__ == "__main__":
    main()
