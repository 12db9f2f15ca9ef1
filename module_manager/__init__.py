"""The Module Manager: manifest → processes, supervision, slot routing, one task per type, robot state, MRI."""
