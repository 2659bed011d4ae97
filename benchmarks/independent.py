"""Independent stress sets (`benchmarks/stress.py --independent`): runs written by reviewers who had
not seen the cases above, to find what the suite's own runs miss. Kept as they were found.

name -> (hw_sim SimConfig fields, crawlerd --set overrides). Wet stretches are metres along the
pipe; the camera at tilt T sees the wall around y + H tan(T) ahead of itself (`view`). A stopgo run
with speed v, accel a, period P, dwell D covers L = v (P - D - v/a) each go and stands at k L during
[k P - D, k P] (`stand`); reverse drives forward 40 % of the run and back 60 %. No crawler import.
"""

import math

SHAKE = dict(bounce_mm=1.0, pitch_jitter_deg=0.3, roll_deg=2.0, sway_mm=1.5)
LIT = dict(lighting=True, vignetting=True, noise_sigma=1.5)
AUTO = ["mount.tilt_deg=auto"]
H_M = 0.2256                      # the mount's camera height below the crown (the default mount)


def wall_image(image):
    return dict(texture="image", texture_image=image, image_mm_per_px=0.4)


def view(tilt_deg):
    """How far ahead of the camera the image centre meets the crown (m)."""
    return H_M * math.tan(math.radians(tilt_deg))


def stand(v, a, period, dwell, k):
    """(position m, stand start s, stand end s) of the k-th stand of a stopgo run."""
    go = period - dwell
    ramp = min(v / a, go / 2)
    return k * a * ramp * (go - ramp), k * period - dwell, k * period


def sg(v, a, P, D):
    """A stopgo profile's fields."""
    return dict(profile="stopgo", speed_m_s=v, accel_m_s2=a, stopgo_period_s=P, stopgo_dwell_s=D)


FIRST = {  # session 12, a first reviewer: seeds 7001-7020
    # --- one disturbance each ---
    "i-wet-lit-15deg-0.25": (dict(tilt_deg=15, speed_m_s=0.25, duration_s=14, seed=7001,
                                  wet_patches=((1.0, 1.8),), wet_highlight=1.5, **LIT), []),
    "i-wet-lit-masonry-32deg-0.5": (dict(tilt_deg=32, speed_m_s=0.5, duration_s=12, seed=7002, texture="masonry",
                                         wet_patches=((2.0, 3.2),), wet_contrast=0.03, **LIT), []),
    "i-blackout-1.5s-15deg-0.3": (dict(tilt_deg=15, speed_m_s=0.3, duration_s=12, seed=7003, exposure_ms=2.0,
                                       led_blackouts=((4.0, 5.5),), **LIT), []),
    "i-blackout-0.3s-32deg-0.7": (dict(tilt_deg=32, speed_m_s=0.7, duration_s=12, seed=7004, exposure_ms=2.0,
                                       led_blackouts=((3.0, 3.3), (8.0, 8.3)), **LIT), []),
    "i-drop-40f-0deg-0.5": (dict(tilt_deg=0, speed_m_s=0.5, duration_s=12, seed=7005,
                                 dropped_bursts=((5.0, 6.33),)), []),
    "i-drop-5f-32deg-0.8": (dict(tilt_deg=32, speed_m_s=0.8, duration_s=12, seed=7006,
                                 dropped_bursts=((3.0, 3.17), (6.0, 6.17), (9.0, 9.17))), []),
    "i-crf37-masonry-shake-0deg-0.2": (dict(tilt_deg=0, speed_m_s=0.2, duration_s=15, seed=7007, texture="masonry",
                                            crf=37, **SHAKE), []),
    "i-crf40-masonry-shake-32deg-0.7": (dict(tilt_deg=32, speed_m_s=0.7, duration_s=10, seed=7008,
                                             texture="masonry", crf=40, **SHAKE), []),
    "i-photo-brick-15deg-0.4": (dict(tilt_deg=15, speed_m_s=0.4, duration_s=12, seed=7009,
                                     **wall_image("skimage:brick")), []),
    "i-photo-grass-32deg-0.15": (dict(tilt_deg=32, speed_m_s=0.15, duration_s=16, seed=7010,
                                      **wall_image("skimage:grass")), []),
    "i-accel-0deg-0.8": (dict(tilt_deg=0, profile="accel", speed_m_s=0.8, accel_m_s2=0.15, duration_s=14,
                              seed=7011), []),
    "i-accel-40deg-0.5": (dict(tilt_deg=40, profile="accel", speed_m_s=0.5, accel_m_s2=0.3, duration_s=12,
                               seed=7013), []),
    "i-reverse-15deg-0.3": (dict(tilt_deg=15, profile="reverse", speed_m_s=0.3, accel_m_s2=0.5, duration_s=14,
                                 seed=7012), []),
    "i-reverse-24deg-0.6": (dict(tilt_deg=24, profile="reverse", speed_m_s=0.6, accel_m_s2=0.8, duration_s=12,
                                 seed=7014, texture="masonry"), []),
    # --- everything at once ---
    "i-aao-stopgo-15deg-0.3": (dict(tilt_deg=15, profile="stopgo", speed_m_s=0.3, accel_m_s2=0.6,
                                    stopgo_period_s=3.5, stopgo_dwell_s=1.0, duration_s=18, seed=7015,
                                    texture="masonry", crf=36, wet_patches=((1.2, 1.7),),
                                    led_blackouts=((6.2, 6.9),), dropped_bursts=((11.5, 12.0),),
                                    exposure_ms=2.0, **SHAKE, **LIT), []),
    "i-aao-reverse-brick-32deg-0.5": (dict(tilt_deg=32, profile="reverse", speed_m_s=0.5, accel_m_s2=0.7,
                                           duration_s=16, seed=7016, crf=35, wet_patches=((1.5, 2.1),),
                                           led_blackouts=((5.0, 5.4),), dropped_bursts=((10.0, 10.3),),
                                           exposure_ms=2.0, **SHAKE, **LIT, **wall_image("skimage:brick")), []),
    "i-aao-stopgo-gravel-40deg-0.6": (dict(tilt_deg=40, profile="stopgo", speed_m_s=0.6, accel_m_s2=0.8,
                                           stopgo_period_s=4.0, stopgo_dwell_s=0.6, duration_s=16, seed=7017,
                                           crf=36, wet_patches=((3.0, 3.8),), led_blackouts=((9.2, 9.7),),
                                           dropped_bursts=((13.0, 13.4),), exposure_ms=2.0, **SHAKE, **LIT,
                                           **wall_image("skimage:gravel")), []),
    "i-aao-stopgo-0deg-0.15": (dict(tilt_deg=0, profile="stopgo", speed_m_s=0.15, accel_m_s2=0.4,
                                    stopgo_period_s=5.0, stopgo_dwell_s=1.5, duration_s=20, seed=7018,
                                    texture="masonry", crf=38, wet_patches=((0.5, 0.9),),
                                    led_blackouts=((7.5, 8.3),), dropped_bursts=((16.0, 16.6),),
                                    exposure_ms=2.0, **SHAKE, **LIT), []),
    # --- default config, tilt estimated online ---
    "i-auto-24deg-0.4": (dict(tilt_deg=24, speed_m_s=0.4, duration_s=15, seed=7019, **LIT), AUTO),
    "i-auto-stopgo-brick-40deg-0.3": (dict(tilt_deg=40, profile="stopgo", speed_m_s=0.3, accel_m_s2=0.5,
                                           stopgo_period_s=3.0, stopgo_dwell_s=0.8, duration_s=15, seed=7020,
                                           **SHAKE, **wall_image("skimage:brick")), AUTO),
}

# controls for the diagnosis of i-aao-stopgo-15deg-0.3 (not part of the table)
_b = FIRST["i-aao-stopgo-15deg-0.3"][0]
CONTROLS = {
    "ctl-aao15-crf18": ({**_b, "crf": 18}, []),                       # the encoder keeps the wet grain
    "ctl-aao15-noblackout": ({**_b, "led_blackouts": ()}, []),        # no blackout during the stand
    "ctl-aao15-wet-only": ({**_b, "led_blackouts": (), "dropped_bursts": ()}, []),
}
FIRST.update(CONTROLS)


BRICK, GRAVEL, GRASS = (wall_image(f"skimage:{w}") for w in ("brick", "gravel", "grass"))

SECOND = {  # session 12, a second reviewer: seeds 8001-8024
    # --- wet stretches under the LED's highlight, photographed walls ---
    "s6-wet-lit-brick-0deg-0.2": (dict(
        tilt_deg=0, speed_m_s=0.2, duration_s=14, seed=8001, wet_patches=((1.0, 1.6),), wet_highlight=1.6,
        **LIT, **BRICK), []),
    # stands 2 (t 5-6 s) with the wet stretch's start edge at the image centre, then drives onto it;
    # stand 3 (t 8-9 s) on the wet stretch
    "s6-wet-stop-on-edge-grass-20deg-0.25": (dict(
        tilt_deg=20, profile="stopgo", speed_m_s=0.25, accel_m_s2=0.5, stopgo_period_s=3.0, stopgo_dwell_s=1.0,
        duration_s=12, seed=8002, wet_patches=((round(stand(0.25, 0.5, 3.0, 1.0, 2)[0] + view(20), 3), 1.40),),
        wet_highlight=1.5, wet_highlight_at=(480.0, 520.0), **LIT, **GRASS), []),
    # stand 2 (t 6.2-7.0 s) with the wet stretch's exit edge at the image centre
    "s6-wet-stop-at-exit-brick-30deg-0.4": (dict(
        tilt_deg=30, profile="stopgo", speed_m_s=0.4, accel_m_s2=0.6, stopgo_period_s=3.5, stopgo_dwell_s=0.8,
        duration_s=14, seed=8003, wet_patches=((1.0, round(stand(0.4, 0.6, 3.5, 0.8, 2)[0] + view(30), 3)),),
        wet_highlight=1.2, wet_highlight_at=(480.0, 480.0), **LIT, **BRICK), []),
    # stand 2 (t 6.8-8.0 s) with the wet stretch entering the far edge of the image, sets off onto it
    "s6-wet-stop-before-gravel-40deg-0.15": (dict(
        tilt_deg=40, profile="stopgo", speed_m_s=0.15, accel_m_s2=0.4, stopgo_period_s=4.0, stopgo_dwell_s=1.2,
        duration_s=16, seed=8004, wet_patches=((round(stand(0.15, 0.4, 4.0, 1.2, 2)[0] + 0.30, 3), 1.35),),
        wet_highlight=1.0, wet_highlight_deg=8.0, wet_highlight_at=(480.0, 400.0), **LIT, **GRAVEL), []),
    # --- LED blackouts ---
    "s6-blackout-0.2s-x3-grass-10deg-0.6": (dict(
        tilt_deg=10, speed_m_s=0.6, duration_s=12, seed=8005, exposure_ms=2.0,
        led_blackouts=((2.0, 2.2), (5.5, 5.7), (9.0, 9.2)), **LIT, **GRASS), []),
    # 2 s dark from braking (stand 1: 2.5-4.0 s) through the stand into the set-off
    "s6-blackout-2s-standing-20deg-0.3": (dict(
        tilt_deg=20, profile="stopgo", speed_m_s=0.3, accel_m_s2=0.5, stopgo_period_s=4.0, stopgo_dwell_s=1.5,
        duration_s=14, seed=8006, exposure_ms=2.0, led_blackouts=((2.3, 4.3),), texture="masonry", **LIT), []),
    # 1 s dark from braking into stand 2 (6.0-7.0 s); 0.4 s dark inside stand 3 (9.5-10.5 s)
    "s6-blackout-brake-and-stand-brick-40deg-0.5": (dict(
        tilt_deg=40, profile="stopgo", speed_m_s=0.5, accel_m_s2=0.8, stopgo_period_s=3.5, stopgo_dwell_s=1.0,
        duration_s=14, seed=8007, exposure_ms=2.0, led_blackouts=((5.7, 6.7), (9.6, 10.0)), **LIT, **BRICK), []),
    # --- dropped-frame bursts ---
    "s6-drop-3f-x4-30deg-0.7": (dict(
        tilt_deg=30, speed_m_s=0.7, duration_s=12, seed=8008,
        dropped_bursts=((2.01, 2.11), (4.51, 4.61), (7.01, 7.11), (9.51, 9.61))), []),
    "s6-drop-60f-masonry-20deg-0.25": (dict(
        tilt_deg=20, speed_m_s=0.25, duration_s=14, seed=8009, texture="masonry",
        dropped_bursts=((6.0, 7.99),)), []),
    # 25 frames while accelerating (0-3 s), 15 while braking (11-14 s)
    "s6-drop-25f-accel-brick-0deg-0.6": (dict(
        tilt_deg=0, profile="accel", speed_m_s=0.6, accel_m_s2=0.2, duration_s=14, seed=8010,
        dropped_bursts=((1.5, 2.32), (12.0, 12.49)), **BRICK), []),
    # --- CRF 33-40 with shake ---
    "s6-crf34-brick-shake-40deg-0.3": (dict(
        tilt_deg=40, speed_m_s=0.3, duration_s=14, seed=8011, crf=34, **SHAKE, **BRICK), []),
    "s6-crf39-gravel-shake-10deg-0.5": (dict(
        tilt_deg=10, speed_m_s=0.5, duration_s=10, seed=8012, crf=39, **SHAKE, **GRAVEL), []),
    # --- accel / reverse with disturbances ---
    "s6-accel-wet-blackout-grass-30deg-0.8": (dict(
        tilt_deg=30, profile="accel", speed_m_s=0.8, accel_m_s2=0.25, duration_s=14, seed=8013, exposure_ms=2.0,
        wet_patches=((4.0, 5.0),), wet_highlight=1.4, wet_highlight_at=(480.0, 560.0),
        led_blackouts=((12.0, 12.6),), **LIT, **GRASS), []),
    # 24 frames lost around the reversal at 6.0 s
    "s6-reverse-drop-grass-20deg-0.4": (dict(
        tilt_deg=20, profile="reverse", speed_m_s=0.4, accel_m_s2=0.5, duration_s=15, seed=8014, crf=33,
        dropped_bursts=((5.7, 6.49),), **GRASS), []),
    # the wet stretch crossed forward and back (reversal at 6.4 s, 1.18 m)
    "s6-reverse-wet-crf35-shake-brick-0deg-0.2": (dict(
        tilt_deg=0, profile="reverse", speed_m_s=0.2, accel_m_s2=0.4, duration_s=16, seed=8015, crf=35,
        wet_patches=((0.7, 1.0),), wet_highlight=1.8, **SHAKE, **LIT, **BRICK), []),
    # --- everything at once: wet + blackout + drops + CRF >= 34 + shake ---
    # stands at 0.6/1.2/1.8/2.4 m (2.5-3.5, 6-7, 9.5-10.5, 13-14 s); stand 2 on the wet stretch's start,
    # dark through it into the set-off; 12 frames lost at the end of stand 3 into its set-off
    "s6-aao-stopgo-brick-0deg-0.3": (dict(
        tilt_deg=0, profile="stopgo", speed_m_s=0.3, accel_m_s2=0.6, stopgo_period_s=3.5, stopgo_dwell_s=1.0,
        duration_s=16, seed=8016, crf=35, wet_patches=((1.15, 1.55),), wet_highlight=1.6,
        led_blackouts=((6.3, 7.3),), dropped_bursts=((10.2, 10.59),), exposure_ms=2.0,
        **SHAKE, **LIT, **BRICK), []),
    # stand 1 (3.2-4 s) with the wet start edge in view, 15 frames lost on the set-off onto it;
    # dark from braking into stand 3 (11.2-12 s)
    "s6-aao-stopgo-gravel-20deg-0.5": (dict(
        tilt_deg=20, profile="stopgo", speed_m_s=0.5, accel_m_s2=0.8, stopgo_period_s=4.0, stopgo_dwell_s=0.8,
        duration_s=16, seed=8017, crf=37,
        wet_patches=((round(stand(0.5, 0.8, 4.0, 0.8, 1)[0] + view(20), 3), 2.2),), wet_highlight=1.3,
        wet_highlight_at=(480.0, 600.0), led_blackouts=((11.0, 11.8),), dropped_bursts=((4.0, 4.49),),
        exposure_ms=2.0, **SHAKE, **LIT, **GRAVEL), []),
    # stands at 0.3/0.6/0.9/1.2 m; stand 2 (5-6 s) with the wet start edge centred, stand 3 (8-9 s) at the
    # exit edge and dark 0.4 s there; 30 frames lost from the end of stand 4 (11-12 s) into the set-off
    "s6-aao-stopgo-grass-30deg-0.2": (dict(
        tilt_deg=30, profile="stopgo", speed_m_s=0.2, accel_m_s2=0.4, stopgo_period_s=3.0, stopgo_dwell_s=1.0,
        duration_s=15, seed=8018, crf=34,
        wet_patches=((round(stand(0.2, 0.4, 3.0, 1.0, 2)[0] + view(30), 3),
                      round(stand(0.2, 0.4, 3.0, 1.0, 3)[0] + view(30) - 0.03, 3)),),
        wet_highlight=1.3, wet_highlight_at=(480.0, 500.0), led_blackouts=((8.2, 8.6),),
        dropped_bursts=((11.6, 12.59),), exposure_ms=2.0, **SHAKE, **LIT, **GRASS), []),
    # forward to 2.85 m (reversal at 5.6 s, dark through it), back to -1.68 m: the wet stretch both ways
    "s6-aao-reverse-brick-40deg-0.6": (dict(
        tilt_deg=40, profile="reverse", speed_m_s=0.6, accel_m_s2=0.7, duration_s=14, seed=8019, crf=36,
        wet_patches=((1.2, 1.8),), wet_highlight=1.5, wet_highlight_at=(480.0, 560.0),
        led_blackouts=((5.3, 6.0),), dropped_bursts=((9.0, 9.49),), exposure_ms=2.0,
        **SHAKE, **LIT, **BRICK), []),
    # a crawl: forward to 0.35 m, reversal at 7.2 s inside 1.2 s dark, 60 frames lost backing up
    "s6-aao-reverse-gravel-10deg-0.05": (dict(
        tilt_deg=10, profile="reverse", speed_m_s=0.05, accel_m_s2=0.2, duration_s=18, seed=8020, crf=38,
        wet_patches=((0.12, 0.30),), wet_highlight=1.8, led_blackouts=((6.8, 8.0),),
        dropped_bursts=((12.0, 13.99),), exposure_ms=2.0, **SHAKE, **LIT, **GRAVEL), []),
    # fast: stands at 1.28/2.56/3.84 m (2.4-3, 5.4-6, 8.4-9 s); stand 2 on the wet stretch, dark there;
    # 12 frames lost at the end of stand 3 into its set-off
    "s6-aao-stopgo-masonry-40deg-0.8": (dict(
        tilt_deg=40, profile="stopgo", speed_m_s=0.8, accel_m_s2=1.0, stopgo_period_s=3.0, stopgo_dwell_s=0.6,
        duration_s=12, seed=8021, crf=38, texture="masonry", wet_patches=((2.6, 3.2),), wet_highlight=1.5,
        wet_highlight_at=(480.0, 420.0), led_blackouts=((5.5, 5.9),), dropped_bursts=((8.9, 9.29),),
        exposure_ms=2.0, **SHAKE, **LIT), []),
    # --- tilt estimated online (mount.tilt_deg=auto) ---
    "s6-auto-gravel-10deg-0.3": (dict(
        tilt_deg=10, speed_m_s=0.3, duration_s=12, seed=8022, crf=28, **LIT, **GRAVEL), AUTO),
    # everything at once as well: stand 2 (6-7 s) with the wet start edge centred, dark in stand 3
    "s6-auto-aao-stopgo-grass-30deg-0.35": (dict(
        tilt_deg=30, profile="stopgo", speed_m_s=0.35, accel_m_s2=0.6, stopgo_period_s=3.5, stopgo_dwell_s=1.0,
        duration_s=15, seed=8023, crf=34,
        wet_patches=((round(stand(0.35, 0.6, 3.5, 1.0, 2)[0] + view(30), 3), 1.9),), wet_highlight=1.3,
        wet_highlight_at=(480.0, 540.0), led_blackouts=((9.6, 10.2),), dropped_bursts=((3.4, 3.79),),
        exposure_ms=2.0, **SHAKE, **LIT, **GRASS), AUTO),
    "s6-auto-reverse-masonry-0deg-0.5": (dict(
        tilt_deg=0, profile="reverse", speed_m_s=0.5, accel_m_s2=0.8, duration_s=12, seed=8024, crf=34,
        texture="masonry", dropped_bursts=((7.0, 7.29),), **SHAKE), AUTO),
}

THIRD = {  # session 12, a third reviewer: seeds 9001-9012, set-offs into a blind stretch
    # stand 2 (5-6 s) with the wet start edge 2 cm past the image centre; sets off onto it under the highlight
    "r8-wet-edge-setoff-brick-10deg-0.3": (dict(
        tilt_deg=10, **sg(0.3, 0.6, 3.0, 1.0), duration_s=12, seed=9001,
        wet_patches=((round(stand(0.3, 0.6, 3.0, 1.0, 2)[0] + view(10) + 0.02, 3), 1.6),), wet_highlight=1.6,
        wet_highlight_at=(480.0, 450.0), **LIT, **BRICK), []),
    # dark from 0.4 s before the end of stand 2 (5.8-7 s) to 0.6 s into its set-off
    "r8-blackout-setoff-grass-30deg-0.2": (dict(
        tilt_deg=30, **sg(0.2, 0.4, 3.5, 1.2), duration_s=14, seed=9002, exposure_ms=2.0,
        led_blackouts=((6.6, 7.6),), **LIT, **GRASS), []),
    # 12 frames lost across the set-off of stand 1 (2.2-3 s) and 18 across stand 3's (8.2-9 s); CRF 34, shake
    "r8-drop-setoff-gravel-40deg-0.4": (dict(
        tilt_deg=40, **sg(0.4, 0.8, 3.0, 0.8), duration_s=12, seed=9003, crf=34,
        dropped_bursts=((2.8, 3.2), (8.9, 9.5)), **SHAKE, **GRAVEL), []),
    # stand 1 (3.2-4 s) with the wet start edge centred; dark 0.3 s before the end of stand 2 (7.2-8 s) into
    # its set-off; 15 frames lost at stand 3's set-off (12 s); CRF 36, shake
    "r8-aao-stopgo-brick-20deg-0.5": (dict(
        tilt_deg=20, **sg(0.5, 0.8, 4.0, 0.8), duration_s=14, seed=9004, crf=36,
        wet_patches=((round(stand(0.5, 0.8, 4.0, 0.8, 1)[0] + view(20), 3), 2.9),), wet_highlight=1.4,
        led_blackouts=((7.7, 8.5),), dropped_bursts=((11.9, 12.4),), exposure_ms=2.0, **SHAKE, **LIT, **BRICK), []),
    # reversal at 5.6 s, dark 5.2-6.3 s through it; CRF 33, shake
    "r8-reverse-blackout-turn-gravel-0deg-0.3": (dict(
        tilt_deg=0, profile="reverse", speed_m_s=0.3, accel_m_s2=0.5, duration_s=14, seed=9005, crf=33,
        exposure_ms=2.0, led_blackouts=((5.2, 6.3),), **SHAKE, **LIT, **GRAVEL), []),
    # reversal at 4.8 s; wet stretch crossed both ways; 20 frames lost right as it sets off backwards
    "r8-reverse-wet-drop-grass-35deg-0.6": (dict(
        tilt_deg=35, profile="reverse", speed_m_s=0.6, accel_m_s2=0.8, duration_s=12, seed=9006,
        wet_patches=((1.3, 1.9),), wet_highlight=1.5, dropped_bursts=((4.75, 5.42),), **LIT, **GRASS), []),
    # stand 2 (6.8-8 s) with the wet exit edge at the image centre, sets off off it; masonry, CRF 38, shake
    "r8-wet-exit-setoff-masonry-25deg-0.15": (dict(
        tilt_deg=25, **sg(0.15, 0.4, 4.0, 1.2), duration_s=16, seed=9007, crf=38, texture="masonry",
        wet_patches=((0.3, round(stand(0.15, 0.4, 4.0, 1.2, 2)[0] + view(25), 3)),), wet_highlight=1.5,
        **SHAKE, **LIT), []),
    # dark from the middle of stand 2 (5.4-6.5 s) to 0.8 s into its set-off
    "r8-blackout-midstand-setoff-brick-0deg-0.35": (dict(
        tilt_deg=0, **sg(0.35, 0.7, 3.25, 1.1), duration_s=13, seed=9008, exposure_ms=2.0,
        led_blackouts=((5.9, 7.3),), **LIT, **BRICK), []),
    # a crawl: 1.2 s of frames lost from the end of stand 2 (8-10 s) into its set-off, wet stretch ahead
    "r8-drop-long-setoff-grass-15deg-0.1": (dict(
        tilt_deg=15, **sg(0.1, 0.3, 5.0, 2.0), duration_s=16, seed=9009,
        wet_patches=((round(stand(0.1, 0.3, 5.0, 2.0, 2)[0] + view(15) + 0.05, 3), 0.9),),
        dropped_bursts=((9.6, 10.8),), **LIT, **GRASS), []),
    # reverse, crawl; wet stretch both ways, dark through the reversal (6 s), 15 frames lost backing up; CRF 37
    "r8-aao-reverse-brick-40deg-0.2": (dict(
        tilt_deg=40, profile="reverse", speed_m_s=0.2, accel_m_s2=0.4, duration_s=15, seed=9010, crf=37,
        wet_patches=((0.45, 0.7),), wet_highlight=1.6, led_blackouts=((5.6, 6.5),), dropped_bursts=((8.0, 8.5),),
        exposure_ms=2.0, **SHAKE, **LIT, **BRICK), []),
    # --- controls: dark strictly inside a stand, light back 0.3 s before the set-off ---
    "ctl8-stand-blackout-gravel-20deg-0.3": (dict(
        tilt_deg=20, **sg(0.3, 0.6, 3.5, 1.5), duration_s=12, seed=9011, exposure_ms=2.0,
        led_blackouts=((5.7, 6.7),), **LIT, **GRAVEL), []),
    "ctl8-stand-blackout-brick-35deg-0.5": (dict(
        tilt_deg=35, **sg(0.5, 0.8, 4.0, 1.6), duration_s=14, seed=9012, crf=35, exposure_ms=2.0,
        led_blackouts=((2.6, 3.6), (10.6, 11.6)), **SHAKE, **LIT, **BRICK), []),
}

FOURTH = {  # session 13, a fourth reviewer: periodic walls and motion changes inside gaps (seeds 7001-7027,
    # in their own runs; the fields as the reviewer wrote them). "rib": masonry of short blocks
    "r5-rev-drop0.7-brick100-24deg-0.5": ({'tilt_deg': 24, 'profile': 'reverse', 'speed_m_s': 0.5, 'accel_m_s2': 1.0, 'duration_s': 8, 'texture': 'masonry', 'brick_mm': (90.0, 65.0), 'mortar_mm': 10.0, 'crf': 34, 'dropped_bursts': ((2.85, 3.55),), 'seed': 7001}, []),
    "r5-rev-blackout0.8-brick150-shake-40deg-0.6": ({'tilt_deg': 40, 'profile': 'reverse', 'speed_m_s': 0.6, 'accel_m_s2': 1.2, 'duration_s': 8, 'texture': 'masonry', 'brick_mm': (140.0, 70.0), 'mortar_mm': 10.0, 'crf': 38, 'led_blackouts': ((2.8, 3.6),), 'seed': 7002, 'bounce_mm': 1.5, 'pitch_jitter_deg': 0.4, 'roll_deg': 3.0, 'sway_mm': 2.0}, []),
    "r5-rev-drop1.0-brick70-0deg-0.3": ({'tilt_deg': 0, 'profile': 'reverse', 'speed_m_s': 0.3, 'accel_m_s2': 0.6, 'duration_s': 10, 'texture': 'masonry', 'brick_mm': (60.0, 50.0), 'mortar_mm': 10.0, 'crf': 32, 'dropped_bursts': ((3.5, 4.5),), 'seed': 7003}, []),
    "r5-rev-hard2.5-drop0.6-brick100-12deg-0.5": ({'tilt_deg': 12, 'profile': 'reverse', 'speed_m_s': 0.5, 'accel_m_s2': 2.5, 'duration_s': 8, 'texture': 'masonry', 'brick_mm': (92.0, 60.0), 'mortar_mm': 8.0, 'crf': 33, 'dropped_bursts': ((2.9, 3.5),), 'seed': 7004}, []),
    "r5-stop-go-in-drop0.9-brick148-12deg-0.4": ({'tilt_deg': 12, 'profile': 'stopgo', 'speed_m_s': 0.4, 'accel_m_s2': 1.0, 'stopgo_period_s': 3.0, 'stopgo_dwell_s': 0.4, 'duration_s': 9, 'texture': 'masonry', 'brick_mm': (138.0, 65.0), 'mortar_mm': 10.0, 'crf': 36, 'dropped_bursts': ((2.3, 3.2),), 'seed': 7005}, []),
    "r5-setoff-in-drop0.6-brick96-shake-30deg-0.6": ({'tilt_deg': 30, 'profile': 'stopgo', 'speed_m_s': 0.6, 'accel_m_s2': 1.2, 'stopgo_period_s': 4.0, 'stopgo_dwell_s': 1.5, 'duration_s': 10, 'texture': 'masonry', 'brick_mm': (86.0, 65.0), 'mortar_mm': 10.0, 'crf': 33, 'dropped_bursts': ((3.8, 4.4),), 'seed': 7006, 'bounce_mm': 1.5, 'pitch_jitter_deg': 0.4, 'roll_deg': 3.0, 'sway_mm': 2.0}, []),
    "r5-hardbrake3-at-drop-start-0deg-0.8": ({'tilt_deg': 0, 'profile': 'stopgo', 'speed_m_s': 0.8, 'accel_m_s2': 3.0, 'stopgo_period_s': 3.0, 'stopgo_dwell_s': 1.2, 'duration_s': 9, 'texture': 'masonry', 'crf': 30, 'dropped_bursts': ((1.53, 2.1), (4.53, 5.1)), 'seed': 7007}, []),
    "r5-brake1.5-at-drop-start-bigshake-40deg-0.6": ({'tilt_deg': 40, 'profile': 'stopgo', 'speed_m_s': 0.6, 'accel_m_s2': 1.5, 'stopgo_period_s': 3.0, 'stopgo_dwell_s': 1.0, 'duration_s': 9, 'texture': 'masonry', 'brick_mm': (110.0, 60.0), 'mortar_mm': 8.0, 'crf': 35, 'dropped_bursts': ((1.6, 2.1), (4.6, 5.1), (7.6, 8.1)), 'seed': 7008, 'bounce_mm': 2.0, 'pitch_jitter_deg': 0.6, 'roll_deg': 4.0, 'sway_mm': 3.0}, []),
    "r5-start-gap-setoff-brick180-20deg-0.5": ({'tilt_deg': 20, 'profile': 'accel', 'speed_m_s': 0.5, 'accel_m_s2': 1.0, 'duration_s': 8, 'texture': 'masonry', 'brick_mm': (170.0, 65.0), 'mortar_mm': 10.0, 'crf': 34, 'dropped_bursts': ((0.1, 0.6),), 'seed': 7009}, []),
    "r5-setoff1.4-out-of-drop0.35-shake-35deg-0.9": ({'tilt_deg': 35, 'profile': 'stopgo', 'speed_m_s': 0.9, 'accel_m_s2': 1.4, 'stopgo_period_s': 4.0, 'stopgo_dwell_s': 1.5, 'duration_s': 9, 'texture': 'masonry', 'brick_mm': (120.0, 65.0), 'mortar_mm': 10.0, 'crf': 35, 'dropped_bursts': ((4.0, 4.35),), 'seed': 7010, 'bounce_mm': 1.5, 'pitch_jitter_deg': 0.4, 'roll_deg': 3.0, 'sway_mm': 2.0}, []),
    "r5-rev-three-drops-short-gaps-brick80-35deg-0.4": ({'tilt_deg': 35, 'profile': 'reverse', 'speed_m_s': 0.4, 'accel_m_s2': 0.8, 'duration_s': 7.5, 'texture': 'masonry', 'brick_mm': (72.0, 60.0), 'mortar_mm': 8.0, 'crf': 35, 'dropped_bursts': ((2.0, 2.5), (2.62, 3.0), (3.12, 3.6)), 'seed': 7011}, []),
    "r5-constant-bigshake-drops-40deg-0.5": ({'tilt_deg': 40, 'profile': 'constant', 'speed_m_s': 0.5, 'duration_s': 8, 'texture': 'masonry', 'crf': 38, 'dropped_bursts': ((2.0, 2.4), (4.0, 4.6), (6.0, 6.3)), 'seed': 7012, 'bounce_mm': 2.0, 'pitch_jitter_deg': 0.6, 'roll_deg': 4.0, 'sway_mm': 3.0}, []),
    "r5-photo-brick-rev-blackout0.8-15deg-0.7": ({'tilt_deg': 15, 'profile': 'reverse', 'speed_m_s': 0.7, 'accel_m_s2': 1.5, 'duration_s': 6, 'texture': 'image', 'texture_image': 'skimage:brick', 'image_mm_per_px': 0.4, 'crf': 30, 'led_blackouts': ((2.0, 2.8),), 'seed': 7013, 'bounce_mm': 1.0, 'pitch_jitter_deg': 0.3, 'roll_deg': 2.0, 'sway_mm': 1.5}, []),
    "r5-rev-drop0.4-rib50-24deg-0.25": ({'tilt_deg': 24, 'profile': 'reverse', 'speed_m_s': 0.25, 'accel_m_s2': 1.25, 'duration_s': 8, 'texture': 'masonry', 'brick_mm': (44.0, 50.0), 'mortar_mm': 6.0, 'crf': 34, 'dropped_bursts': ((3.0, 3.4),), 'seed': 7021}, []),
    "r5-stop-in-drop0.45-rib52-0deg-0.3": ({'tilt_deg': 0, 'profile': 'stopgo', 'speed_m_s': 0.3, 'accel_m_s2': 1.5, 'stopgo_period_s': 3.0, 'stopgo_dwell_s': 1.0, 'duration_s': 9, 'texture': 'masonry', 'brick_mm': (46.0, 60.0), 'mortar_mm': 6.0, 'crf': 36, 'dropped_bursts': ((1.8, 2.25), (4.8, 5.25), (7.8, 8.25)), 'seed': 7022}, []),
    "r5-setoff-in-drop0.3-rib47-shake-30deg-0.6": ({'tilt_deg': 30, 'profile': 'stopgo', 'speed_m_s': 0.6, 'accel_m_s2': 1.5, 'stopgo_period_s': 3.0, 'stopgo_dwell_s': 1.2, 'duration_s': 9, 'texture': 'masonry', 'brick_mm': (41.0, 60.0), 'mortar_mm': 6.0, 'crf': 33, 'dropped_bursts': ((2.95, 3.25), (5.95, 6.25)), 'seed': 7023, 'bounce_mm': 1.5, 'pitch_jitter_deg': 0.4, 'roll_deg': 3.0, 'sway_mm': 2.0}, []),
    "r5-constant-shake-drops-40deg-0.15": ({'tilt_deg': 40, 'profile': 'constant', 'speed_m_s': 0.15, 'duration_s': 8, 'texture': 'masonry', 'crf': 36, 'dropped_bursts': ((1.5, 1.8), (3.0, 3.35), (4.5, 4.75), (6.0, 6.4)), 'seed': 7024, 'bounce_mm': 1.5, 'pitch_jitter_deg': 0.4, 'roll_deg': 3.0, 'sway_mm': 2.0}, []),
    "r5-start-drop-setoff-rib48-12deg-0.3": ({'tilt_deg': 12, 'profile': 'accel', 'speed_m_s': 0.3, 'accel_m_s2': 0.6, 'duration_s': 6, 'texture': 'masonry', 'brick_mm': (42.0, 60.0), 'mortar_mm': 6.0, 'crf': 34, 'dropped_bursts': ((0.05, 0.4),), 'seed': 7025}, []),
    "r5-rev-blackout0.45-rib67-shake-35deg-0.3": ({'tilt_deg': 35, 'profile': 'reverse', 'speed_m_s': 0.3, 'accel_m_s2': 1.5, 'duration_s': 7, 'texture': 'masonry', 'brick_mm': (61.0, 60.0), 'mortar_mm': 6.0, 'crf': 35, 'led_blackouts': ((2.6, 3.05),), 'seed': 7026, 'bounce_mm': 1.5, 'pitch_jitter_deg': 0.4, 'roll_deg': 3.0, 'sway_mm': 2.0}, []),
    "r5-rev-hard2-drop0.35-rib61-20deg-0.35": ({'tilt_deg': 20, 'profile': 'reverse', 'speed_m_s': 0.35, 'accel_m_s2': 2.0, 'duration_s': 7, 'texture': 'masonry', 'brick_mm': (55.0, 60.0), 'mortar_mm': 6.0, 'crf': 33, 'dropped_bursts': ((2.625, 2.975),), 'seed': 7027}, []),
}

BIGSHAKE = dict(bounce_mm=1.5, pitch_jitter_deg=0.4, roll_deg=3.0, sway_mm=2.0)
DARK = dict(exposure_ms=2.0)        # a short exposure, as with the LEDs strobed


def _mas(length_mm, height_mm=65.0, mortar_mm=10.0):
    return dict(texture="masonry", brick_mm=(length_mm, height_mm), mortar_mm=mortar_mm)


_sg = sg


FIFTH = {  # session 14, a fifth reviewer: brakes and set-offs of 0.3-3 m/s^2 at the edges of blind
    # stretches, inspection stands while blind, creeping, chains of short gaps, a sediment hump (seeds
    # 8031-8046; the fields as the reviewer wrote them)
    # --- brakes and set-offs at the edges of blind stretches ---
    # 3 m/s^2: brakes 1.8-2.0 s as the LEDs go out (dark 1.8-2.5), sets off at 6.0 s 0.1 s before they
    # come back (dark 5.6-6.1), brakes 7.8-8.0 s inside dark 7.75-8.3; 100 mm blocks
    "r6-brake3-into-dark-setoff3-in-dark-mas100-10deg-0.6": (dict(
        tilt_deg=10, **_sg(0.6, 3.0, 3.0, 1.0), duration_s=9, seed=8031, crf=32,
        led_blackouts=((1.8, 2.5), (5.6, 6.1), (7.75, 8.3)), **DARK, **LIT, **_mas(100.0)), []),
    # 0.3 m/s^2: brakes 2.17-3.0 s onto a wet stretch (blind from y 0.395, t ~2.0 s), stands 2.5 s on
    # it, sets off 5.5-6.33 s still blind (until y 0.685, t ~6.6 s)
    "r6-brake0.3-stand2.5-setoff0.3-in-wet-grass-25deg-0.25": (dict(
        tilt_deg=25, **_sg(0.25, 0.3, 5.5, 2.5), duration_s=11, seed=8032, crf=30,
        wet_patches=((0.42, 0.90),), wet_highlight=1.4, **LIT, **GRASS), []),
    # 0.5 m/s^2 brake from 0.8 m/s (1.9-3.5 s): 30 frames lost in its middle (2.3-3.3 s); the set-off at
    # 5.0 s starts 0.05 s into a 0.65 s burst; concrete
    "r6-brake0.5-in-drop-setoff-at-drop-start-concrete-35deg-0.8": (dict(
        tilt_deg=35, **_sg(0.8, 0.5, 5.0, 1.5), duration_s=9, seed=8033, crf=30,
        dropped_bursts=((2.3, 3.3), (4.95, 5.6))), []),
    # reversal (2 m/s^2, 3.75-4.25 s) at y 1.875 inside a wet stretch (blind for y > 1.714: ~3.4-4.6 s)
    "r6-reverse2-in-wet-brick-shake-15deg-0.5": (dict(
        tilt_deg=15, profile="reverse", speed_m_s=0.5, accel_m_s2=2.0, duration_s=10, seed=8034, crf=33,
        wet_patches=((1.70, 2.10),), wet_highlight=1.5, **SHAKE, **LIT, **BRICK), []),
    # starts dark (0-1.2 s) while setting off at 0.4 m/s^2 (ramp 0-1 s); its final brake (7-8 s) is
    # almost all in a 1 s burst of lost frames (6.9-7.9 s): the run ends just after the camera returns
    "r6-start-dark-setoff0.4-end-drop-brake-grass-20deg-0.4": (dict(
        tilt_deg=20, profile="accel", speed_m_s=0.4, accel_m_s2=0.4, duration_s=8, seed=8035, crf=31,
        led_blackouts=((0.0, 1.2),), dropped_bursts=((6.9, 7.9),), **DARK, **LIT, **GRASS), []),
    # starts with 13 frames lost while setting off at 2.5 m/s^2; lost frames across the set-off of go 2
    # (3.45-3.75 s), the end of the brake into stand 2 (5.3-5.45 s) and two bursts in go 3's set-off;
    # 300 mm blocks
    "r6-start-drop-setoff2.5-short-drops-mas300-30deg-0.7": (dict(
        tilt_deg=30, **_sg(0.7, 2.5, 3.5, 1.5), duration_s=10, seed=8036, crf=34,
        dropped_bursts=((0.0, 0.45), (3.45, 3.75), (5.3, 5.45), (6.95, 7.15), (7.25, 7.45)),
        **_mas(300.0, 75.0, 12.0)), []),
    # --- inspection stands while blind ---
    # dark 3.0-6.8 s: the brake (0.8 m/s^2, 3.125-3.5 s), a 3 s stand, 0.3 s of the set-off
    "r6-inspect3s-dark-brake-setoff-brick-0deg-0.3": (dict(
        tilt_deg=0, **_sg(0.3, 0.8, 6.5, 3.0), duration_s=10, seed=8037, crf=28,
        led_blackouts=((3.0, 6.8),), **DARK, **LIT, **BRICK), []),
    # a 5 s stand at a leak: blind on the wet stretch from y 0.434 (t ~2.3 s, cruising) through the brake
    # (2.6-3 s), the stand (3-8 s) and the set-off (8-8.4 s) until y 0.727 (t ~9.3 s); CRF 35
    "r6-inspect5s-on-leak-wet-mas215-10deg-0.2": (dict(
        tilt_deg=10, **_sg(0.2, 0.5, 8.0, 5.0), duration_s=11, seed=8038, crf=35,
        wet_patches=((0.40, 0.85),), wet_highlight=1.4, **LIT, **_mas(215.0)), []),
    # the camera stalls while the crawler stands 2 s for photos: 66 frames lost from the end of the brake
    # (1.5 m/s^2) to 0.1 s into the set-off (2.4-4.6 s); 48 lost strictly inside stand 2 (7.2-8.8 s)
    "r6-inspect2s-in-drops-mas60-shake-35deg-0.5": (dict(
        tilt_deg=35, **_sg(0.5, 1.5, 4.5, 2.0), duration_s=11, seed=8039, crf=30,
        dropped_bursts=((2.4, 4.6), (7.2, 8.8)), **SHAKE, **_mas(60.0, 60.0, 8.0)), []),
    # --- creeping ---
    # 0.03 m/s for 12 s (0.36 m): six bursts of lost frames, CRF 36, shake
    "r6-creep0.03-drops-mas150-shake-40deg": (dict(
        tilt_deg=40, speed_m_s=0.03, duration_s=12, seed=8040, crf=36,
        dropped_bursts=((1.0, 1.3), (2.0, 2.2), (2.5, 2.8), (6.0, 7.5), (9.0, 9.1), (9.25, 9.35)),
        **SHAKE, **_mas(150.0)), []),
    # 0.05 m/s, 0.3 m/s^2, 2 s stands (2-4, 6-8, 10-12 s): dark from 0.33 s before the first brake to 0.5 s
    # after its set-off (1.5-4.5 s); dark across the second set-off (7.9-8.1 s)
    "r6-creep0.05-stopgo-dark-stands-grass-20deg": (dict(
        tilt_deg=20, **_sg(0.05, 0.3, 4.0, 2.0), duration_s=12, seed=8041, crf=30,
        led_blackouts=((1.5, 4.5), (7.9, 8.1)), **DARK, **LIT, **GRASS), []),
    # --- chains of short gaps ---
    # accelerating at 0.3 m/s^2 (0-1.5 s): dark, lost, dark, lost; braking (7.5-9 s): lost, dark, lost, dark
    "r6-gap-chain-accel0.3-brick-30deg-0.45": (dict(
        tilt_deg=30, profile="accel", speed_m_s=0.45, accel_m_s2=0.3, duration_s=9, seed=8042, crf=36,
        led_blackouts=((0.6, 0.8), (1.1, 1.35), (7.85, 8.05), (8.4, 8.6)),
        dropped_bursts=((0.9, 1.0), (1.45, 1.6), (7.6, 7.75), (8.15, 8.3)), **DARK, **LIT, **BRICK), []),
    # reversal (0.6 m/s^2, 4.22-5.38 s) at y 1.476 inside a wet stretch (blind for y > 1.36), 9 frames
    # lost just after the turn (4.9-5.2 s); CRF 38, shake
    "r6-reverse0.6-wet-drop-mas215-crf38-shake-40deg-0.35": (dict(
        tilt_deg=40, profile="reverse", speed_m_s=0.35, accel_m_s2=0.6, duration_s=12, seed=8043, crf=38,
        wet_patches=((1.45, 1.90),), wet_highlight=1.6, dropped_bursts=((4.9, 5.2),), **SHAKE, **LIT,
        **_mas(215.0)), []),
    # --- walls, compression, ride ---
    # a 12 mm sediment hump (y 1.2-2.1 m, t 2-3.5 s): the camera rises toward the crown and the car pitches
    # (tilt 5 -> 2.7 up the slope, 7.3 down it); dark over its crest (2.4-2.9 s); CRF 40
    "r6-sediment-hump-dark-brick-crf40-5deg-0.6": (dict(
        tilt_schedule=((0.0, 5.0), (1.95, 5.0), (2.05, 2.7), (2.45, 2.7), (2.55, 5.0), (2.95, 5.0), (3.05, 7.3),
                       (3.45, 7.3), (3.55, 5.0)),
        height_profile=((1.2, 0.0), (1.5, 12.0), (1.8, 12.0), (2.1, 0.0)),
        speed_m_s=0.6, duration_s=7, seed=8044, crf=40, led_blackouts=((2.4, 2.9),), **DARK, **LIT, **BRICK), []),
    # fast, 1.2 m/s^2: brakes (6.25-7 s) onto a wet stretch, stands on it, sets off off it (blind
    # ~6.45-8.3 s); 21 frames lost from the last brake into stand 3 (10.9-11.6 s); CRF 38, big shake
    "r6-fast-stopgo-wet-stand-mas215-crf38-shake-40deg-0.9": (dict(
        tilt_deg=40, **_sg(0.9, 1.2, 4.0, 1.0), duration_s=12, seed=8045, crf=38,
        wet_patches=((3.95, 4.45),), wet_highlight=1.3, dropped_bursts=((10.9, 11.6),), **BIGSHAKE, **LIT,
        **_mas(215.0)), []),
    # back to back: wet wall (blind from t ~2.68 s, cruising), dark (2.87-3.6 s: the 1 m/s^2 brake
    # 2.95-3.3 s), lost frames (3.6-4.7 s: the end of the stand and the set-off at 4.5 s); CRF 34, shake
    "r6-wet-dark-drop-chain-brake1-setoff1-grass-0deg-0.35": (dict(
        tilt_deg=0, **_sg(0.35, 1.0, 4.5, 1.2), duration_s=10, seed=8046, crf=34,
        wet_patches=((0.80, 1.02),), wet_highlight=1.5, led_blackouts=((2.87, 3.6),),
        dropped_bursts=((3.6, 4.7),), **DARK, **SHAKE, **LIT, **GRASS), []),
}

INDEPENDENT = {**FIRST, **SECOND, **THIRD, **FOURTH, **FIFTH}
